"""Tests of the experiment loaders: ``experiment.toml``, ``jumps.csv`` and batch tables."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from granbayes.errors import InputError
from granbayes.experiment import (
    BATCH_EXPERIMENT_COLUMNS,
    BATCH_FORCE_COLUMNS,
    COMMAND_NAMES,
    CommandSettings,
    Experiment,
    Robot,
    load_batch_table,
    load_experiment,
    load_jumps,
)

REFERENCE_HEIGHTS = Path(__file__).resolve().parent / "data" / "reference-heights.csv"

FULL_TOML = """\
[robot]
m_motor = 1.5
m_rod = 0.25
m_foot = 0.12
k_spring = 6000      # an integer: converted to float
c_spring = 0
foot_radius = 0.04
grain_density = 2500.0

[command]
amplitude_mm = 15.0
freq_hz = 12.5
delay_ms = 0
settle_periods = 2.5

[bed]
phi_c = 0.6
"""

JUMPS_HEADER = "phi,command,height_mm\n"


def write(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` (creating folders) and return the path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def assert_located(
    error: pytest.ExceptionInfo[InputError],
    file: Path,
    row: int | None,
    column: str | None,
    *pieces: str,
) -> None:
    """Check that an InputError names the file, the row and the column (and contains pieces)."""
    message = str(error.value)
    assert file.name in message
    assert error.value.file == str(file)
    assert error.value.row == row
    assert error.value.column == column
    if row is not None:
        assert f"row {row}" in message
    else:
        assert "row " not in message
    if column is not None:
        assert f"column '{column}'" in message
    for piece in pieces:
        assert piece in message


# --------------------------------------------------------------------------------------
# load_experiment
# --------------------------------------------------------------------------------------


def test_folder_without_toml_gives_defaults(tmp_path: Path) -> None:
    experiment = load_experiment(tmp_path)
    assert experiment == Experiment(source=str(tmp_path))
    assert experiment.source == str(tmp_path)


def test_full_toml_round_trip(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", FULL_TOML)
    expected = Experiment(
        robot=Robot(1.5, 0.25, 0.12, 6000.0, 0.0, 0.04, 2500.0),
        command=CommandSettings(15.0, 12.5, 0.0, 2.5),
        phi_c=0.6,
    )
    from_folder = load_experiment(tmp_path)
    from_file = load_experiment(str(file))
    assert from_folder == dataclasses.replace(expected, source=str(tmp_path))
    assert from_file == dataclasses.replace(expected, source=str(file))
    assert type(from_file.robot.k_spring) is float
    assert type(from_file.command.delay_ms) is float


def test_partial_toml_keeps_defaults(tmp_path: Path) -> None:
    file = write(tmp_path / "any-name.toml", "[command]\nfreq_hz = 8\n")
    experiment = load_experiment(file)
    assert experiment.command.freq_hz == 8.0
    assert experiment.robot == Robot()
    assert experiment.phi_c == Experiment().phi_c


def test_empty_toml_gives_defaults(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", "# nothing set\n")
    assert load_experiment(file) == Experiment(source=str(file))


def test_missing_path(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere"
    with pytest.raises(InputError) as error:
        load_experiment(missing)
    assert_located(error, missing, None, None, "no such file")


def test_unknown_key(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", "[robot]\nm_rod = 0.2\nm_motr = 1.0\n")
    with pytest.raises(InputError) as error:
        load_experiment(tmp_path)
    assert_located(error, file, 3, "robot.m_motr", "m_motor", "grain_density", "m_motor'?")


def test_unknown_section(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", "[robot]\nm_rod = 0.2\n\n[robo]\nm_rod = 1\n")
    with pytest.raises(InputError) as error:
        load_experiment(file)
    assert_located(error, file, 4, "robo", "[robot]", "[command]", "[bed]")


def test_top_level_key_is_unknown(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", "m_motor = 1.0\n")
    with pytest.raises(InputError) as error:
        load_experiment(file)
    assert_located(error, file, 1, "m_motor", "allowed sections")


def test_section_must_be_a_table(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", "robot = 3\n")
    with pytest.raises(InputError) as error:
        load_experiment(file)
    assert_located(error, file, 1, "robot", "expected a table")


@pytest.mark.parametrize(
    ("value", "kind"),
    [
        ("true", "a boolean"),
        ("false", "a boolean"),
        ('"1.0"', "a string"),
        ("[1.0, 2.0]", "an array"),
        ("{ a = 1 }", "a table"),
        ("1979-05-27", "a date/time"),
    ],
)
def test_wrong_type_rejected(tmp_path: Path, value: str, kind: str) -> None:
    file = write(tmp_path / "experiment.toml", f"[command]\n\nfreq_hz = {value}\n")
    with pytest.raises(InputError) as error:
        load_experiment(file)
    assert_located(error, file, 3, "command.freq_hz", "expected a number", kind)


def test_bool_rejected_although_int_subclass(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", "[robot]\nm_motor = 1\nc_spring = true\n")
    with pytest.raises(InputError) as error:
        load_experiment(tmp_path)
    assert_located(error, file, 3, "robot.c_spring", "expected a number, got a boolean (true)")


@pytest.mark.parametrize(
    ("section", "key", "value"),
    [
        ("robot", "m_motor", "0"),
        ("robot", "m_rod", "-0.1"),
        ("robot", "m_foot", "0.0"),
        ("robot", "k_spring", "-5"),
        ("robot", "c_spring", "-1e-9"),
        ("robot", "foot_radius", "0"),
        ("robot", "grain_density", "-1100"),
        ("robot", "m_motor", "inf"),
        ("robot", "m_motor", "nan"),
        ("robot", "m_motor", "1" + "0" * 400),
        ("command", "amplitude_mm", "0"),
        ("command", "freq_hz", "-10"),
        ("command", "delay_ms", "-1"),
        ("command", "settle_periods", "-0.5"),
        ("command", "delay_ms", "-inf"),
        ("bed", "phi_c", "0"),
        ("bed", "phi_c", "1"),
        ("bed", "phi_c", "1.2"),
    ],
)
def test_out_of_range_rejected(tmp_path: Path, section: str, key: str, value: str) -> None:
    file = write(tmp_path / "experiment.toml", f"[{section}]\n{key} = {value}\n")
    with pytest.raises(InputError) as error:
        load_experiment(file)
    assert_located(error, file, 2, f"{section}.{key}")


def test_zero_allowed_where_non_negative(tmp_path: Path) -> None:
    text = "[robot]\nc_spring = 0\n[command]\ndelay_ms = 0.0\nsettle_periods = 0\n"
    experiment = load_experiment(write(tmp_path / "experiment.toml", text))
    assert experiment.robot.c_spring == 0.0
    assert experiment.command.delay_ms == 0.0
    assert experiment.command.settle_periods == 0.0


def test_malformed_toml_reports_line(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", "[robot]\nm_motor = 1.0\nm_rod 0.2\n")
    with pytest.raises(InputError) as error:
        load_experiment(tmp_path)
    assert_located(error, file, 3, None, "malformed TOML")


def test_duplicate_toml_key_is_malformed(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", "[robot]\nm_rod = 0.2\nm_rod = 0.3\n")
    with pytest.raises(InputError) as error:
        load_experiment(file)
    assert "malformed TOML" in str(error.value)
    assert error.value.file == str(file)


def test_dotted_and_inline_keys_are_located(tmp_path: Path) -> None:
    file = write(tmp_path / "experiment.toml", '# header\nrobot.m_rod = 0.2\nrobot.m_foot = "x"\n')
    with pytest.raises(InputError) as error:
        load_experiment(file)
    assert_located(error, file, 3, "robot.m_foot")

    file = write(tmp_path / "inline.toml", "\n\ncommand = { freq_hz = 10, delay_ms = -1 }\n")
    with pytest.raises(InputError) as error:
        load_experiment(file)
    assert_located(error, file, 3, "command.delay_ms", ">= 0")


def test_not_utf8(tmp_path: Path) -> None:
    file = tmp_path / "experiment.toml"
    file.write_bytes(b"[robot]\nm_rod = 0.2 # \xff\n")
    with pytest.raises(InputError) as error:
        load_experiment(file)
    assert_located(error, file, None, None, "UTF-8")


def test_toml_keys_match_dataclasses() -> None:
    robot_fields = tuple(f.name for f in dataclasses.fields(Robot))
    command_fields = tuple(f.name for f in dataclasses.fields(CommandSettings))
    assert BATCH_EXPERIMENT_COLUMNS == robot_fields + command_fields


# --------------------------------------------------------------------------------------
# load_jumps
# --------------------------------------------------------------------------------------


def test_jumps_minimal_filled_from_default_experiment(tmp_path: Path) -> None:
    write(tmp_path / "jumps.csv", JUMPS_HEADER + "0.58,single,61.5\n0.6,stutter,40\n")
    jumps = load_jumps(tmp_path)
    assert list(jumps.columns) == [
        "phi",
        "command",
        "height_mm",
        "freq_hz",
        "amplitude_mm",
        "delay_ms",
        "settle_periods",
    ]
    assert jumps["phi"].tolist() == [0.58, 0.6]
    assert jumps["command"].tolist() == ["single", "stutter"]
    assert jumps["height_mm"].tolist() == [61.5, 40.0]
    defaults = CommandSettings()
    for name in ("freq_hz", "amplitude_mm", "delay_ms", "settle_periods"):
        assert jumps[name].dtype == np.float64
        assert (jumps[name] == getattr(defaults, name)).all()
    assert jumps["phi"].dtype == np.float64
    assert jumps["height_mm"].dtype == np.float64
    assert list(jumps.index) == [0, 1]


def test_jumps_filled_from_given_experiment(tmp_path: Path) -> None:
    file = write(tmp_path / "data.csv", JUMPS_HEADER + "0.58,preload,61.5\n")
    experiment = Experiment(command=CommandSettings(12.0, 7.0, 30.0, 1.0))
    jumps = load_jumps(file, experiment)
    assert jumps.loc[0, "amplitude_mm"] == 12.0
    assert jumps.loc[0, "freq_hz"] == 7.0
    assert jumps.loc[0, "delay_ms"] == 30.0
    assert jumps.loc[0, "settle_periods"] == 1.0


def test_jumps_per_row_override(tmp_path: Path) -> None:
    text = (
        "phi,command,height_mm,freq_hz,delay_ms\n"
        "0.58,delayed_stutter,61.5,12,80\n"
        "0.59,delayed_stutter,60,,\n"
        "0.60,single,59,8.5,\n"
    )
    write(tmp_path / "jumps.csv", text)
    experiment = Experiment(command=CommandSettings(freq_hz=9.0, delay_ms=25.0))
    jumps = load_jumps(tmp_path, experiment)
    assert jumps["freq_hz"].tolist() == [12.0, 9.0, 8.5]
    assert jumps["delay_ms"].tolist() == [80.0, 25.0, 25.0]
    assert jumps["amplitude_mm"].tolist() == [20.0] * 3
    assert list(jumps.columns[:5]) == ["phi", "command", "height_mm", "freq_hz", "delay_ms"]


def test_jumps_trial_and_extra_columns_kept(tmp_path: Path) -> None:
    text = (
        "operator,phi,command,height_mm,trial,note\n"
        "ann,0.58,single,61.5,1,first try\n"
        "bob,0.58,single,60.0,,\n"
        "ann,0.58,single,62.0,3.0,007\n"
    )
    jumps = load_jumps(write(tmp_path / "jumps.csv", text))
    assert list(jumps.columns[:6]) == ["operator", "phi", "command", "height_mm", "trial", "note"]
    assert jumps["operator"].tolist() == ["ann", "bob", "ann"]
    assert jumps["note"].tolist() == ["first try", "", "007"]
    assert str(jumps["trial"].dtype) == "Int64"
    assert jumps["trial"].iloc[0] == 1
    assert jumps["trial"].iloc[1] is pd.NA
    assert jumps["trial"].iloc[2] == 3


def test_jumps_whitespace_bom_and_blank_lines(tmp_path: Path) -> None:
    text = "\ufeff phi , command ,height_mm \n\n 0.58 , single , 61.5 \n,,\n0.6,preload,70\n\n"
    jumps = load_jumps(write(tmp_path / "jumps.csv", text))
    assert jumps["phi"].tolist() == [0.58, 0.6]
    assert jumps["command"].tolist() == ["single", "preload"]
    assert jumps["height_mm"].tolist() == [61.5, 70.0]


def test_jumps_trailing_empty_unnamed_column_dropped(tmp_path: Path) -> None:
    text = "phi,command,height_mm,\n0.58,single,61.5,\n"
    jumps = load_jumps(write(tmp_path / "jumps.csv", text))
    assert "" not in jumps.columns
    assert len(jumps) == 1


def test_jumps_quoted_multiline_cell(tmp_path: Path) -> None:
    text = 'phi,command,height_mm,note\n0.58,single,61.5,"two\nlines"\n0.6,single,x,\n'
    file = write(tmp_path / "jumps.csv", text)
    with pytest.raises(InputError) as error:
        load_jumps(file)
    # The quoted record spans lines 2-3; the bad one starts on line 4, data row 3.
    assert_located(error, file, 3, "height_mm")


@pytest.mark.parametrize(
    ("rows", "row", "column", "piece"),
    [
        ("0.58,single,61.5\n0.58,jump,60\n", 2, "command", "delayed_stutter_preload"),
        ("0.58,Single,61.5\n", 1, "command", "did you mean 'single'"),
        ("0.58,,61.5\n", 1, "command", "empty cell"),
        ("abc,single,61.5\n", 1, "phi", "expected a number, got 'abc'"),
        ("0.58,single,61.5\n,single,61.5\n", 2, "phi", "empty cell"),
        ("nan,single,61.5\n", 1, "phi", "finite"),
        ("inf,single,61.5\n", 1, "phi", "finite"),
        ("0,single,61.5\n", 1, "phi", "(0, 1)"),
        ("1,single,61.5\n", 1, "phi", "(0, 1)"),
        ("1.5,single,61.5\n", 1, "phi", "(0, 1)"),
        ("-0.2,single,61.5\n", 1, "phi", "(0, 1)"),
        ("0.58,single,\n", 1, "height_mm", "empty cell"),
        ("0.58,single,NaN\n", 1, "height_mm", "finite"),
        ("0.58,single,-inf\n", 1, "height_mm", "finite"),
        ("0.58,single,1_000\n", 1, "height_mm", "expected a number"),
        ("0.58,single,61.5\n0.58,single,61.5,9\n", 2, None, "4 fields"),
        ("0.58,single\n", 1, None, "2 fields"),
    ],
)
def test_jumps_bad_required_cells(
    tmp_path: Path, rows: str, row: int, column: str | None, piece: str
) -> None:
    file = write(tmp_path / "exp" / "jumps.csv", JUMPS_HEADER + rows)
    with pytest.raises(InputError) as error:
        load_jumps(tmp_path / "exp")
    assert_located(error, file, row, column, piece)


@pytest.mark.parametrize(
    ("column", "value", "piece"),
    [
        ("freq_hz", "0", "> 0"),
        ("freq_hz", "-1", "> 0"),
        ("freq_hz", "inf", "finite"),
        ("amplitude_mm", "0", "> 0"),
        ("amplitude_mm", "ten", "expected a number"),
        ("delay_ms", "-1", ">= 0"),
        ("delay_ms", "nan", "finite"),
        ("settle_periods", "-0.5", ">= 0"),
        ("trial", "1.5", "integer"),
        ("trial", "first", "integer"),
        ("trial", "inf", "integer"),
    ],
)
def test_jumps_bad_optional_cells(tmp_path: Path, column: str, value: str, piece: str) -> None:
    text = f"phi,command,height_mm,{column}\n0.58,single,61.5,\n0.58,single,61.5,{value}\n"
    file = write(tmp_path / "jumps.csv", text)
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, 2, column, piece)


def test_jumps_first_problem_in_file_order(tmp_path: Path) -> None:
    # Row 1 is bad in height_mm (third column), row 2 in phi (first column): row 1 wins.
    text = JUMPS_HEADER + "0.58,single,x\n2,single,61\n"
    file = write(tmp_path / "jumps.csv", text)
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, 1, "height_mm")

    # Two problems in one row: the leftmost column wins.
    text = JUMPS_HEADER + "0.58,single,1\n0.58,walk,x\n"
    write(tmp_path / "jumps.csv", text)
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, 2, "command")


def test_jumps_rows_count_lines_after_header(tmp_path: Path) -> None:
    text = "\n" + JUMPS_HEADER + "0.58,single,61\n\n0.58,single,bad\n"
    file = write(tmp_path / "jumps.csv", text)
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, 3, "height_mm")


@pytest.mark.parametrize("missing", ["phi", "command", "height_mm"])
def test_jumps_missing_required_column(tmp_path: Path, missing: str) -> None:
    header = ",".join(name for name in ("phi", "command", "height_mm") if name != missing)
    file = write(tmp_path / "jumps.csv", header + "\n0.5,0.5\n")
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, None, missing, "missing required column")


def test_jumps_misspelt_column_gets_a_hint(tmp_path: Path) -> None:
    file = write(tmp_path / "jumps.csv", "phi,command,height\n0.5,single,3\n")
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, None, "height_mm", "did you mean 'height'")


@pytest.mark.parametrize(
    ("text", "piece"),
    [
        ("", "empty file"),
        ("\n\n  \n", "empty file"),
        (JUMPS_HEADER, "no data rows"),
        (JUMPS_HEADER + "\n,,\n", "no data rows"),
    ],
)
def test_jumps_empty_file(tmp_path: Path, text: str, piece: str) -> None:
    file = write(tmp_path / "jumps.csv", text)
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, None, None, piece)


def test_jumps_duplicate_column(tmp_path: Path) -> None:
    file = write(tmp_path / "jumps.csv", "phi,command,height_mm, phi\n0.5,single,3,0.6\n")
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, None, "phi", "duplicate")


def test_jumps_value_in_unnamed_column(tmp_path: Path) -> None:
    file = write(tmp_path / "jumps.csv", "phi,command,height_mm,\n0.5,single,3,\n0.5,single,3,x\n")
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, 2, None, "no header name")


def test_jumps_malformed_quotes(tmp_path: Path) -> None:
    file = write(tmp_path / "jumps.csv", JUMPS_HEADER + '0.5,single,3\n0.5,"single"x,3\n')
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, 2, None, "malformed CSV")

    write(tmp_path / "jumps.csv", JUMPS_HEADER + '0.5,single,3\n0.5,"single,3\n0.5,single,3\n')
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, 2, None, "malformed CSV")


def test_jumps_missing_files(tmp_path: Path) -> None:
    with pytest.raises(InputError) as error:
        load_jumps(tmp_path)
    assert_located(error, tmp_path / "jumps.csv", None, None, "no jumps.csv")

    missing = tmp_path / "missing.csv"
    with pytest.raises(InputError) as error:
        load_jumps(missing)
    assert_located(error, missing, None, None, "no such file")


def test_jumps_not_utf8(tmp_path: Path) -> None:
    file = tmp_path / "jumps.csv"
    file.write_bytes(JUMPS_HEADER.encode() + b"0.5,single,3 \xe9\n")
    with pytest.raises(InputError) as error:
        load_jumps(file)
    assert_located(error, file, None, None, "UTF-8")


# --------------------------------------------------------------------------------------
# load_batch_table
# --------------------------------------------------------------------------------------


def test_reference_heights_load() -> None:
    table = load_batch_table(REFERENCE_HEIGHTS)
    assert len(table) > 0
    assert set(table["command"]) <= set(COMMAND_NAMES)
    assert table["phi"].dtype == np.float64
    for name in BATCH_FORCE_COLUMNS + BATCH_EXPERIMENT_COLUMNS:
        if name in table.columns:
            assert table[name].dtype == np.float64
    assert "height_mm" in table.columns
    assert all(isinstance(value, str) for value in table["height_mm"])
    assert np.isfinite(table["height_mm"].astype(float)).all()


def test_batch_minimal_and_empty_cells(tmp_path: Path) -> None:
    text = "command,phi,k,r_unload,freq_hz,label\nsingle,0.6,3000,,12,a\npreload,0.61,,20,,b\n"
    table = load_batch_table(write(tmp_path / "in.csv", text))
    assert list(table.columns) == ["command", "phi", "k", "r_unload", "freq_hz", "label"]
    assert table["command"].tolist() == ["single", "preload"]
    assert table["phi"].tolist() == [0.6, 0.61]
    assert table.loc[0, "k"] == 3000.0
    assert math.isnan(table.loc[1, "k"])
    assert math.isnan(table.loc[0, "r_unload"])
    assert table.loc[1, "r_unload"] == 20.0
    assert math.isnan(table.loc[1, "freq_hz"])
    assert table["label"].tolist() == ["a", "b"]


def test_batch_zero_force_parameters_allowed(tmp_path: Path) -> None:
    text = "command,phi,k,c_d,kappa,k2,b,c_comp\nstutter,0.6,0,0,0,0,0,0\n"
    table = load_batch_table(write(tmp_path / "in.csv", text))
    assert (table.loc[0, ["k", "c_d", "kappa", "k2", "b", "c_comp"]] == 0.0).all()


def test_batch_r_unload_one_allowed(tmp_path: Path) -> None:
    """r_unload = 1 (the perfectly elastic bed) is the smallest allowed value."""
    text = "command,phi,k,r_unload\nsingle,0.6,3000,1\nsingle,0.6,3000,1.0\n"
    table = load_batch_table(write(tmp_path / "in.csv", text))
    assert table["r_unload"].tolist() == [1.0, 1.0]


@pytest.mark.parametrize(
    ("column", "value", "piece"),
    [
        ("k", "-1", ">= 0"),
        ("c_d", "abc", "expected a number"),
        ("kappa", "inf", "finite"),
        ("r_unload", "0", ">= 1"),
        ("r_unload", "0.5", ">= 1"),
        ("k2", "-0.1", ">= 0"),
        ("b", "nan", "finite"),
        ("m_motor", "0", "> 0"),
        ("m_foot", "-1", "> 0"),
        ("c_spring", "-1", ">= 0"),
        ("grain_density", "0", "> 0"),
        ("amplitude_mm", "0", "> 0"),
        ("settle_periods", "-1", ">= 0"),
        ("phi", "1", "(0, 1)"),
        ("phi", "", "empty cell"),
        ("command", "hop", "valid values"),
    ],
)
def test_batch_bad_cells(tmp_path: Path, column: str, value: str, piece: str) -> None:
    good = {"command": "single", "phi": "0.6", "k": "3000", column: "1"}
    if column == "command":
        good[column] = "single"
    if column == "phi":
        good[column] = "0.5"
    bad = {**good, column: value}
    header = ",".join(good)
    text = f"{header}\n{','.join(good.values())}\n{','.join(bad.values())}\n"
    file = write(tmp_path / "in.csv", text)
    with pytest.raises(InputError) as error:
        load_batch_table(file)
    assert_located(error, file, 2, column, piece)


@pytest.mark.parametrize("missing", ["command", "phi"])
def test_batch_missing_required_column(tmp_path: Path, missing: str) -> None:
    header = "phi,k" if missing == "command" else "command,k"
    file = write(tmp_path / "in.csv", f"{header}\nsingle,1\n")
    with pytest.raises(InputError) as error:
        load_batch_table(file)
    assert_located(error, file, None, missing, "missing required column")


def test_batch_folder_rejected(tmp_path: Path) -> None:
    with pytest.raises(InputError) as error:
        load_batch_table(tmp_path)
    assert_located(error, tmp_path, None, None, "folder")


def test_force_registry_docstring_examples() -> None:
    """The examples in granbayes/forces.py run and print what they claim."""
    import doctest

    import granbayes.forces

    assert doctest.testmod(granbayes.forces).failed == 0
