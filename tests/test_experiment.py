"""Tests of the experiment loaders: ``experiment.toml``, ``jumps.csv`` and batch tables."""

from __future__ import annotations

import csv
import dataclasses
import difflib
import io
import math
import random
import tempfile
from collections.abc import Sequence
from pathlib import Path
from unittest import mock

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import granbayes._tables as experiment_module
from granbayes._errors import InputError
from granbayes._experiment import Experiment, Robot, load_experiment
from granbayes._measurements import (
    BATCH_EXPERIMENT_COLUMNS,
    BATCH_FORCE_COLUMNS,
    load_batch_table,
    load_jumps,
)
from granbayes.commands import COMMAND_NAMES, CommandSettings

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


@pytest.mark.parametrize("pandas_cells", [0, 10**9])
def test_jumps_line_breaks_of_any_kind(tmp_path: Path, pandas_cells: int) -> None:
    """CR LF and a lone CR break lines as LF does (rows are counted the same), with or
    without a byte-order mark, whichever parser reads the numbers."""
    rows = ["phi,command,height_mm", "0.58,single,61.5", "0.6,preload,70"]
    frames = []
    with mock.patch.object(experiment_module, "_PANDAS_MIN_CELLS", pandas_cells):
        for newline in ("\n", "\r\n", "\r"):
            for mark in (b"", b"\xef\xbb\xbf"):
                file = tmp_path / f"jumps{len(frames)}.csv"
                file.write_bytes(mark + newline.join(rows).encode())
                frames.append(load_jumps(file))
                file.write_bytes(mark + newline.join([*rows, "0.6,hop,1"]).encode())
                with pytest.raises(InputError) as error:
                    load_jumps(file)
                assert_located(error, file, 3, "command")
    for frame in frames[1:]:
        pd.testing.assert_frame_equal(frame, frames[0])


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


# --------------------------------------------------------------------------------------
# Bulk checks against a per-cell reference
# --------------------------------------------------------------------------------------
#
# The loaders check whole columns in bulk (granbayes._experiment, "The same checks for whole
# columns"). The reference below is the plain per-cell algorithm, written out here on its
# own: the csv module record by record, every cell through float(). On random small tables
# with random bad cells, both must name the same first bad cell with the same message, or
# give the same values.

#: Numeric columns of the generated tables: (lower bound, bound allowed, required cells).
REFERENCE_NUMBERS: dict[str, dict[str, tuple[float, bool, bool]]] = {
    "batch": {
        "phi": (0.0, False, True),
        "k": (0.0, True, False),
        "c_d": (0.0, True, False),
        "r_unload": (1.0, True, False),
        "m_motor": (0.0, False, False),
        "freq_hz": (0.0, False, False),
        "delay_ms": (0.0, True, False),
    },
    "jumps": {
        "phi": (0.0, False, True),
        "height_mm": (-math.inf, False, True),
        "freq_hz": (0.0, False, False),
        "settle_periods": (0.0, True, False),
    },
}
REFERENCE_REQUIRED = {"batch": ("command", "phi", "k"), "jumps": ("phi", "command", "height_mm")}
REFERENCE_OPTIONAL = {
    "batch": ("c_d", "r_unload", "m_motor", "freq_hz", "delay_ms", "note"),
    "jumps": ("trial", "freq_hz", "settle_periods", "note"),
}


def reference_number(text: str) -> float | None:
    """A cell as a number: float(), but never with an underscore."""
    if "_" in text:
        return None
    try:
        return float(text)
    except ValueError:
        return None


def reference_cell(kind: str, name: str, text: str) -> tuple[object, str | None]:
    """One cell's value and problem, by the rules of docs/data-format.md, spelled out."""
    if name == "command":
        if text in COMMAND_NAMES:
            return text, None
        if not text:
            return text, f"empty cell; valid values: {', '.join(COMMAND_NAMES)}"
        close = difflib.get_close_matches(text, COMMAND_NAMES, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        return text, f"unknown command '{text}'{hint}; valid values: {', '.join(COMMAND_NAMES)}"
    if name == "trial":
        if not text:
            return None, None
        number = reference_number(text)
        if number is None or not math.isfinite(number) or number != int(number):
            return None, f"expected an integer, got '{text}'"
        if not -(2**63) <= number < 2**63:
            return None, f"expected an integer of at most 64 bits, got '{text}'"
        return int(number), None
    if name not in REFERENCE_NUMBERS[kind]:
        return text, None  # a text column
    lower, closed, required = REFERENCE_NUMBERS[kind][name]
    if not text:
        return math.nan, ("empty cell, expected a number" if required else None)
    number = reference_number(text)
    if number is None:
        return math.nan, f"expected a number, got '{text}'"
    if not math.isfinite(number):
        return number, f"expected a finite number, got '{text}'"
    if name == "phi":
        if not 0.0 < number < 1.0:
            return number, f"got '{text}', must be in the open interval (0, 1)"
    elif not (number >= lower if closed else number > lower):
        return number, f"got '{text}', must be {'>=' if closed else '>'} {lower:g}"
    return number, None


def reference_load(kind: str, text: str) -> tuple:
    """What loading ``text`` must give: ("error", row, column, message) or ("ok", columns)."""
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    header: list[str] | None = None
    header_line = 0
    records = []
    line_end = 0
    try:
        for fields in reader:
            start, line_end = line_end + 1, reader.line_num
            stripped = [cell.strip() for cell in fields]
            if not any(stripped):
                continue
            if header is None:
                header, header_line = stripped, start
            else:
                records.append((start - header_line, stripped))
    except csv.Error as err:
        row = line_end + 1 - header_line if header is not None else None
        return ("error", row, None, f"malformed CSV: {err}")
    assert header is not None and records, "the generator always writes a header and a row"
    problems = []
    columns: dict[str, list] = {name: [] for name in header if name}
    for row, fields in records:
        if len(fields) != len(header):
            problems.append(
                (row, -1, None, f"{len(fields)} fields, but the header has {len(header)}")
            )
            fields = (fields + [""] * len(header))[: len(header)]
        for position, (name, cell) in enumerate(zip(header, fields, strict=True)):
            if not name:
                if cell:
                    message = f"value '{cell}' in column {position + 1}, which has no header name"
                    problems.append((row, position, None, message))
                continue
            value, problem = reference_cell(kind, name, cell)
            columns[name].append(value)
            if problem is not None:
                problems.append((row, position, name, problem))
    if problems:
        row, _, column, message = min(problems, key=lambda problem: problem[:2])
        return ("error", row, column, message)
    if kind == "jumps":  # rows without a command setting take the experiment's
        for name in ("freq_hz", "settle_periods"):
            default = getattr(CommandSettings(), name)
            if name in columns:
                columns[name] = [default if math.isnan(v) else v for v in columns[name]]
    return ("ok", {name: [repr(value) for value in values] for name, values in columns.items()})


def loaded(kind: str, file: Path, header: list[str]) -> tuple:
    """What the loader gives, in the form of :func:`reference_load`."""
    try:
        frame = load_batch_table(file) if kind == "batch" else load_jumps(file)
    except InputError as err:
        return ("error", err.row, err.column, err.message)
    columns = {}
    for name in (name.strip() for name in header):
        if not name:
            continue
        values = frame[name].tolist()
        if name == "trial":
            values = [None if value is pd.NA else int(value) for value in values]
        elif name in REFERENCE_NUMBERS[kind]:
            values = [float(value) for value in values]
        columns[name] = [repr(value) for value in values]
    return ("ok", columns)


#: Cells of numeric columns: numbers in many spellings, and what is not one.
NUMBER_SPELLINGS = (
    *("0.6", ".5", "5.", "+0.25", "3000", "1e3", "1E-2", "0", "-0", "12.5", "0.612"),
    *("\uff10.\uff16", "\u0661\u0662"),  # fullwidth 0.6, Arabic-Indic 12: float() takes them
    *("", "abc", "1_000", "nan", "NaN", "inf", "-inf", "Infinity", "1e400", "-1", "1.5"),
    *("1e", "--1", "0x10", "e5", ".", "1e+", "-", "+.5e-3", "1.2.3", "1,5"),
    *("1e19", "9223372036854775807", "-9223372036854775808", "1.7976931348623159e308"),
)
#: The bad cells the bulk checks could most easily get wrong.
TRICKY_SPELLINGS = (
    "1_000",
    "1_0.5",
    "inf",
    "-Infinity",
    "1e400",
    "nan",
    "",
    "-1",
    "0",
    "1e19",
    "1\n2",
    "1,5",
)
COMMAND_SPELLINGS = (*COMMAND_NAMES, "hop", "Single", "", "stuter", "delayed")
TEXT_SPELLINGS = ("a", "b c", "", "1_000", "x,y", 'say "hi"', "two\nlines")


class Pick:
    """Random choices for the table generator: from hypothesis (``draw``) or a seeded
    ``random.Random`` (``rng``)."""

    def __init__(self, draw: st.DrawFn | None = None, rng: random.Random | None = None):
        self.draw, self.rng = draw, rng

    def below(self, n: int) -> int:
        """An integer in [0, n)."""
        return self.draw(st.integers(0, n - 1)) if self.draw else self.rng.randrange(n)

    def choice(self, options: Sequence[str]) -> str:
        """One of ``options``."""
        return options[self.below(len(options))]

    def chance(self, one_in: int) -> bool:
        """True once in ``one_in``."""
        return self.below(one_in) == 0

    def uniform(self, low: float, high: float) -> float:
        """A float in [low, high]."""
        if self.draw:
            return self.draw(st.floats(low, high))
        return self.rng.uniform(low, high)


def good_cell(kind: str, name: str, pick: Pick) -> str:
    """A cell the rules accept in column ``name``."""
    if name == "command":
        return pick.choice(COMMAND_NAMES)
    if name == "trial":
        return pick.choice(["", "1", "2", "3.0", "-0", "1e2"])
    if name == "phi":
        if pick.chance(3):
            return pick.choice(["0.6", ".5", "+0.25", "5E-1", "\uff10.\uff16"])
        return repr(pick.uniform(0.01, 0.99))
    if not name:
        return ""
    if name not in REFERENCE_NUMBERS[kind]:
        return pick.choice(["", "a", "b c", "7"])
    if not REFERENCE_NUMBERS[kind][name][2] and pick.chance(4):
        return ""  # not given
    if pick.chance(3):
        return pick.choice(["3000", "1e3", "12.5", "5.", "1.5", "+2", "1E1"])
    return repr(pick.uniform(1.0, 1e6))


def bad_cell(kind: str, name: str, pick: Pick) -> str:
    """A cell for column ``name``, most of them bad."""
    if name == "command":
        return pick.choice(COMMAND_SPELLINGS[len(COMMAND_NAMES) :])
    if name == "note":
        return pick.choice(TEXT_SPELLINGS)
    if not name:
        return "x"
    way = pick.below(4)
    if way == 0:
        return pick.choice(TRICKY_SPELLINGS)
    if way == 1:
        return pick.choice(NUMBER_SPELLINGS)
    if way == 2:
        if pick.chance(3):
            return pick.choice(["inf", "-inf", "nan", "0.0", "-0.0", "1e+300", "5e-324"])
        return repr(pick.uniform(-2.0, 2.0) * 10 ** pick.below(8))
    return "".join(pick.choice("0123456789.eE+-_ ") for _ in range(1 + pick.below(5)))


def random_table(pick: Pick) -> tuple[str, list[str], str]:
    """A small CSV table (kind, header, text): good cells, a few bad ones at random places,
    and random quoting, padding, blank lines and rows of the wrong length."""
    kind = pick.choice(["batch", "jumps"])
    optional = [name for name in REFERENCE_OPTIONAL[kind] if pick.chance(2)]
    names = [*REFERENCE_REQUIRED[kind], *optional] + ([""] if pick.chance(2) else [])
    for index in range(len(names) - 1, 0, -1):  # shuffle
        other = pick.below(index + 1)
        names[index], names[other] = names[other], names[index]
    n_rows = 1 + pick.below(6)
    table = [[good_cell(kind, name, pick) for name in names] for _ in range(n_rows)]
    for _ in range(pick.below(4)):
        row, column = pick.below(n_rows), pick.below(len(names))
        table[row][column] = bad_cell(kind, names[column], pick)
    quoting, padding, irregular = pick.chance(2), pick.chance(2), pick.chance(2)

    def written(text: str) -> str:
        if padding and pick.chance(2):
            text = f" {text}\t"
        if any(c in text for c in ',"\n') and not quoting:
            text = text.replace(",", ";").replace('"', "'").replace("\n", " ")
        if quoting and (pick.chance(2) or any(c in text for c in ',"\n')):
            text = '"' + text.replace('"', '""') + '"'
        return text

    lines = [",".join(names)]
    for cells in table:
        cells = [written(text) for text in cells]
        change = pick.below(12) if irregular else 2
        if change == 0:
            cells.append("extra")
        elif change == 1 and len(cells) > 1:
            cells.pop()
        if irregular and pick.chance(3):
            lines.append(pick.choice(["", ",,", ",,,,", " , "]))  # blank lines
        lines.append(",".join(cells))
    if irregular and pick.chance(2):
        lines.insert(0, "")
    newline = pick.choice(["\n", "\r\n"])
    return kind, names, newline.join(lines) + (newline if pick.chance(2) else "")


def check_against_reference(kind: str, header: list[str], text: str, folder: Path) -> None:
    """Load ``text`` (as ``folder/table.csv``) with numeric columns parsed by pandas'
    reader wherever it applies (as if pandas read a NaN text as NaN too, the path that
    scans for one), and by float() alone (the path of small columns and of other pandas
    versions); each must give what the per-cell reference gives."""
    expected = reference_load(kind, text.replace("\r\n", "\n"))
    file = folder / "table.csv"
    file.write_bytes(text.encode("utf-8"))
    for min_cells, refuses_nan in ((0, True), (0, False), (10**9, True)):
        # refuses_nan=False: the path of a pandas that parsed a NaN text (the text scan)
        with (
            mock.patch.object(experiment_module, "_PANDAS_MIN_CELLS", min_cells),
            mock.patch.object(
                experiment_module, "_pandas_refuses_nan_text", lambda value=refuses_nan: value
            ),
        ):
            assert loaded(kind, file, header) == expected, (min_cells, refuses_nan, text)


@given(case=st.composite(lambda draw: random_table(Pick(draw=draw)))())
@settings(max_examples=200)
def test_bulk_checks_name_the_cell_the_per_cell_rules_name(
    case: tuple[str, list[str], str],
) -> None:
    """The first bad cell in file order and its message, or every value, as cell by cell
    (hypothesis: tables it shrinks to the smallest failing one)."""
    with tempfile.TemporaryDirectory() as folder:
        check_against_reference(*case, Path(folder))


def test_bulk_checks_on_many_random_tables(tmp_path: Path) -> None:
    """The same on 1000 seeded random tables (uniform choices: every spelling of
    :data:`NUMBER_SPELLINGS` and :data:`TRICKY_SPELLINGS` lands in every kind of column)."""
    rng = random.Random(20261126)
    for _ in range(1000):
        check_against_reference(*random_table(Pick(rng=rng)), tmp_path)


def test_pandas_refuses_every_nan_text() -> None:
    """The probe of the installed pandas (which spares every table a scan for ``nan``)
    agrees with what its reader does with each spelling inside a table of numbers."""
    refused = []
    for spelling in experiment_module._NAN_SPELLINGS:
        text = "x\n" + "1.5\n" * 5 + f"{spelling}\n"
        try:
            pd.read_csv(
                io.StringIO(text),
                dtype={"x": np.float64},
                keep_default_na=False,
                na_values={"x": [""]},
                quoting=csv.QUOTE_NONE,
                engine="c",
            )
        except ValueError:
            refused.append(spelling)
    assert experiment_module._pandas_refuses_nan_text() == (
        len(refused) == len(experiment_module._NAN_SPELLINGS)
    )
    assert {"nan", "NaN", "-nan", "+NAN", "nan(1)"} <= set(experiment_module._NAN_SPELLINGS)


@pytest.mark.parametrize("pandas_cells", [0, 10**9])
def test_number_cells_parse_as_float_does(pandas_cells: int) -> None:
    """Each cell of a column as :func:`float` parses it (``_`` refused), whichever parser;
    every spelling first, last and between plain numbers."""
    spellings = sorted({*NUMBER_SPELLINGS, *TRICKY_SPELLINGS, "1,5", " 1", "1\n2", "1e-400"})
    columns = [[text] for text in spellings] + [[text, "1.5", "2"] for text in spellings]
    columns += [["1.5", "2", text] for text in spellings] + [spellings, spellings[::-1]]
    with mock.patch.object(experiment_module, "_PANDAS_MIN_CELLS", pandas_cells):
        for texts in columns:
            values, empty, refused = experiment_module._number_cells(list(texts))
            for text, value, is_empty, is_refused in zip(
                texts, values, empty, refused, strict=True
            ):
                number = reference_number(text)
                assert is_empty == (text == ""), text
                assert is_refused == (bool(text) and number is None), text
                expected = math.nan if number is None else number
                assert repr(float(value)) == repr(expected), text


@pytest.mark.parametrize(
    ("toml", "column", "fragment"),
    [
        ("[robot.uncertainty]\nk_spring = -1.0\n", "robot.uncertainty.k_spring", "finite and >= 0"),
        ("[robot.uncertainty]\nk_sprung = 1.0\n", "robot.uncertainty.k_sprung", "unknown key"),
        ("[robot.uncertainty]\nm_motor = 'a'\n", "robot.uncertainty.m_motor", "expected a number"),
        ("[bed]\nphi_sd = -0.001\n", "bed.phi_sd", ""),
    ],
)
def test_bad_uncertainties_name_the_key(tmp_path, toml: str, column: str, fragment: str) -> None:
    """[robot.uncertainty] and [bed] phi_sd (data-format.md) are read and validated."""
    path = tmp_path / "experiment.toml"
    path.write_text(toml)
    with pytest.raises(InputError) as err:
        load_experiment(path)
    assert column in str(err.value) and fragment in str(err.value)


def test_uncertainties_are_read(tmp_path) -> None:
    path = tmp_path / "experiment.toml"
    path.write_text(
        "[robot]\nk_spring = 5000.0\n[robot.uncertainty]\nk_spring = 150.0\n"
        "m_motor = 0.01\namplitude_mm = 0.5\n[bed]\nphi_c = 0.612\nphi_sd = 0.002\n"
    )
    exp = load_experiment(path)
    assert exp.robot.k_spring == 5000.0
    assert exp.uncertainty == {"k_spring": 150.0, "m_motor": 0.01, "amplitude_mm": 0.5}
    assert exp.phi_sd == 0.002 and exp.uncertain
    (tmp_path / "plain").mkdir()
    assert not load_experiment(tmp_path / "plain").uncertain
