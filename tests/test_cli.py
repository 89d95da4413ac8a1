"""End-to-end tests of the ``granbayes`` command line (in-process and as a real program)."""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from granbayes import __version__
from granbayes._cli import (
    EXIT_FAILED_JUMP,
    EXIT_INPUT,
    EXIT_OK,
    EXIT_UNCONVERGED,
    ProgressBars,
    atomic_path,
    main,
)
from granbayes._datatree import read_datatree
from granbayes._experiment import Experiment, load_experiment
from granbayes._sampler import ProgressInfo
from granbayes._simulator import Heights, Status, simulate, simulate_table
from granbayes._synthetic import write_experiment
from granbayes.commands import COMMAND_NAMES
from granbayes.testing import synthetic_jumps

REFERENCE_HEIGHTS = Path(__file__).resolve().parent / "data" / "reference-heights.csv"

TRAJECTORY_COLUMNS = [
    "t_s",
    "x_rod_mm",
    "x_foot_mm",
    "v_rod_m_s",
    "v_foot_m_s",
    "depth_mm",
    "z_max_mm",
    "ground_force_N",
    "added_mass_kg",
    "mode",
    "alpha_mm",
    "unloading_slope_N_m",
]

ONE_JUMP = ["simulate", "--command", "single", "--phi", "0.612", "--param", "k=3000"]

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def write(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` and return the path."""
    path.write_text(text, encoding="utf-8")
    return path


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """Run ``granbayes argv`` in-process; return exit code, stdout and stderr."""
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_one_error_line(code: int, out: str, err: str, *fragments: str) -> str:
    """Check exit code 2, nothing on stdout and one error line containing ``fragments``."""
    assert code == EXIT_INPUT
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("granbayes: error: ")
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    return lines[0]


def granbayes_program() -> list[str]:
    """The installed ``granbayes`` console script (or the module, if it is not on disk)."""
    script = Path(sys.executable).with_name("granbayes")
    if script.is_file():
        return [str(script)]
    found = shutil.which("granbayes")
    return [found] if found else [sys.executable, "-m", "granbayes._cli"]


# ----------------------------------------------------------------------------------------
# One jump
# ----------------------------------------------------------------------------------------


def test_json_height_matches_simulate(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, *ONE_JUMP, "--param", "c_d=50", "--param", "kappa=0.5", "--json")
    assert code == EXIT_OK, err
    record = json.loads(out)  # exactly one JSON object
    expected = simulate("single", 0.612, {"k": 3000.0, "c_d": 50.0, "kappa": 0.5})
    assert record["height_mm"] == pytest.approx(float(expected.height_mm[0]), abs=1e-9)
    assert record["status"] == "ok"
    assert record["command"] == "single"
    assert record["phi"] == 0.612
    assert record["params"] == {"k": 3000.0, "c_d": 50.0, "kappa": 0.5}
    assert record["effective_params"]["r_unload"] == 20.0
    assert record["robot"]["m_motor"] == 1.0
    assert record["command_settings"]["freq_hz"] == 10.0


def test_json_uses_the_experiment(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    toml = write(tmp_path / "experiment.toml", "[robot]\nm_motor = 1.5\n[command]\nfreq_hz = 12\n")
    code, out, _ = run(
        capsys, *ONE_JUMP[:-2], "--param", "k=5000", "--experiment", str(tmp_path), "--json"
    )
    assert code == EXIT_OK
    record = json.loads(out)
    expected = simulate("single", 0.612, {"k": 5000.0}, experiment=load_experiment(toml))
    assert record["height_mm"] == pytest.approx(float(expected.height_mm[0]), abs=1e-9)
    assert record["robot"]["m_motor"] == 1.5
    assert record["command_settings"]["freq_hz"] == 12.0
    default = simulate("single", 0.612, {"k": 5000.0})
    assert not math.isclose(record["height_mm"], float(default.height_mm[0]))


def test_human_line(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, *ONE_JUMP, "--param", "c_d=50")
    assert code == EXIT_OK
    assert err == ""
    height = float(simulate("single", 0.612, {"k": 3000.0, "c_d": 50.0}).height_mm[0])
    assert out == f"single at phi=0.612: height {height:.2f} mm (ok)\n"


def test_trajectory_csv_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    csv, png = tmp_path / "traj.csv", tmp_path / "traj.png"
    code, out, _ = run(
        capsys,
        *ONE_JUMP[:2],
        "stutter",
        *ONE_JUMP[3:],
        "--param",
        "kappa=1",
        "--trajectory",
        str(csv),
        "--plot",
        str(png),
        "--json",
    )
    assert code == EXIT_OK
    record = json.loads(out)
    data = pd.read_csv(csv)
    assert list(data.columns) == TRAJECTORY_COLUMNS
    assert data["t_s"].iloc[0] == 0.0
    assert np.all(np.diff(data["t_s"]) >= 0.0)
    assert set(data["mode"]) <= {"advancing", "contact", "free"}
    assert data["added_mass_kg"].max() > 0.0
    window = data["t_s"] >= 0.05  # the stutter's height window opens at T/2
    assert data.loc[window, "x_foot_mm"].max() == pytest.approx(record["height_mm"], abs=0.05)
    np.testing.assert_allclose(data["depth_mm"], -data["x_foot_mm"])
    assert png.read_bytes()[:8] == PNG_MAGIC
    assert png.stat().st_size > 20_000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["traj.csv", "traj.png"]


def test_failed_jump_exit_code_3(capsys: pytest.CaptureFixture[str]) -> None:
    # a near-rigid, hugely viscous bed (stiff advancing) exhausts the step budget
    code, out, _ = run(
        capsys, *ONE_JUMP[:-1], "k=1e9", "--param", "r_unload=1e6", "--param", "b=1e6", "--json"
    )
    assert code == EXIT_FAILED_JUMP
    record = json.loads(out)
    assert record["status"].startswith("failed:")
    assert record["height_mm"] is None


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "--version")
    assert code == EXIT_OK
    assert out.strip() == f"granbayes {__version__}"


# ----------------------------------------------------------------------------------------
# Batch mode
# ----------------------------------------------------------------------------------------


def test_batch_reproduces_reference_heights(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out_csv = tmp_path / "out.csv"
    code, out, err = run(
        capsys, "simulate", "--batch", str(REFERENCE_HEIGHTS), "--out", str(out_csv)
    )
    assert code == EXIT_OK, err
    assert out == ""
    assert "already has a height_mm column" in err  # the one-line note
    reference = pd.read_csv(REFERENCE_HEIGHTS)
    result = pd.read_csv(out_csv)
    assert list(result.columns) == [*reference.columns, "status"]
    assert (result["status"] == "ok").all()
    pd.testing.assert_frame_equal(
        result.drop(columns=["height_mm", "status"]), reference.drop(columns="height_mm")
    )
    np.testing.assert_allclose(result["height_mm"], reference["height_mm"], rtol=0, atol=0.05)


def test_batch_keeps_extra_columns_and_threads(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = write(
        tmp_path / "in.csv",
        "trial,command,phi,k,c_d,note\n1,single,0.612,3000,50,a\n2,stutter,0.6,4000,,b c\n",
    )
    out_csv = tmp_path / "out.csv"
    code, _, err = run(
        capsys, "simulate", "--batch", str(table), "--out", str(out_csv), "--threads", "1"
    )
    assert code == EXIT_OK
    assert err == ""
    result = pd.read_csv(out_csv, keep_default_na=False)
    columns = ["trial", "command", "phi", "k", "c_d", "note", "height_mm", "status"]
    assert list(result.columns) == columns
    assert list(result["note"]) == ["a", "b c"]
    assert result["c_d"].iloc[1] == ""  # "not given" stays empty
    expected = simulate("stutter", 0.6, {"k": 4000.0})
    assert float(result["height_mm"].iloc[1]) == pytest.approx(float(expected.height_mm[0]))


def test_batch_output_is_the_input_as_written_plus_results(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Cells are written back as the file spells them (stripped), quoted where needed."""
    table = write(
        tmp_path / "in.csv",
        'command, phi ,k,c_d,note\nsingle, 0.612 ,3000,,"a, b"\nstutter,6e-1,4E3,5.,"say ""hi"""\n',
    )
    out_csv = tmp_path / "out.csv"
    code, _, err = run(capsys, "simulate", "--batch", str(table), "--out", str(out_csv))
    assert code == EXIT_OK, err
    lines = out_csv.read_text().splitlines()
    assert lines[0] == "command,phi,k,c_d,note,height_mm,status"
    assert lines[1].startswith('single,0.612,3000,,"a, b",')
    assert lines[2].startswith('stutter,6e-1,4E3,5.,"say ""hi""",')
    result = pd.read_csv(out_csv, keep_default_na=False)
    assert list(result["note"]) == ["a, b", 'say "hi"']
    expected = simulate("stutter", 0.6, {"k": 4000.0, "c_d": 5.0}).height_mm[0]
    assert float(result["height_mm"].iloc[1]) == float(expected)
    assert lines[2].endswith(f",{float(expected)!r},ok")

    # plain files are copied line by line; height_mm and status columns are replaced
    plain = write(tmp_path / "plain.csv", "status,command,phi,k,height_mm\nx,single,0.6,1e3,7\n")
    code, out, err = run(capsys, "simulate", "--batch", str(plain), "--out", "-")
    assert code == EXIT_OK, err
    height = float(simulate("single", 0.6, {"k": 1000.0}).height_mm[0])
    assert out == f"status,command,phi,k,height_mm\nok,single,0.6,1e3,{height!r}\n"


def test_batch_rows_equal_single_jumps(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Rows grouped into command programs (per-row settings, empty cells: the defaults)
    give the heights of the same jumps simulated one by one, bit for bit."""
    rng = np.random.default_rng(7)
    n = 40
    table = pd.DataFrame(
        {
            "command": rng.choice(COMMAND_NAMES, n),
            "phi": rng.uniform(0.59, 0.63, n),
            "k": rng.uniform(1e3, 1e4, n),
            "c_d": rng.uniform(0, 100, n),
            "freq_hz": rng.choice([8.0, 12.0, np.nan], n),
            "delay_ms": rng.choice([30.0, np.nan], n),
            "settle_periods": rng.choice([1.0, 2.0], n),
        }
    )
    experiment = Experiment().replace(freq_hz=9.0, amplitude_mm=15.0)
    result = simulate_table(table, experiment, n_threads=1)
    for row in table.itertuples():
        settings = {"settle_periods": row.settle_periods}
        settings |= {} if math.isnan(row.freq_hz) else {"freq_hz": row.freq_hz}
        settings |= {} if math.isnan(row.delay_ms) else {"delay_ms": row.delay_ms}
        jump = simulate(
            row.command,
            row.phi,
            {"k": row.k, "c_d": row.c_d},
            experiment=experiment.replace(**settings),
        )
        assert result["height_mm"].iloc[row.Index] == jump.height_mm[0], row
        assert result["status"].iloc[row.Index] == Status(int(jump.status[0])).label
    assert str(result["status"].dtype) == "str"


def test_status_labels_by_lookup() -> None:
    """Labels of every status code as :attr:`Status.label`; an unknown code is refused."""
    codes = np.array([status.value for status in Status] * 2, dtype=np.int8)
    heights = Heights(np.zeros(codes.size), codes, np.zeros(codes.size, dtype=np.int64))
    assert heights.status_labels == [Status(int(code)).label for code in codes]
    for bad in (-1, len(Status)):
        with pytest.raises(ValueError, match="not a valid Status"):
            _ = Heights(np.zeros(1), np.array([bad], dtype=np.int8), np.zeros(1)).status_labels


# ----------------------------------------------------------------------------------------
# Bad input: exit code 2, one line naming file, row and column, nothing written
# ----------------------------------------------------------------------------------------


def test_unknown_command_in_batch_row(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    table = write(
        tmp_path / "bad_rows.csv",
        "command,phi,k\nsingle,0.6,3000\nstutter,0.6,3000\nhop,0.6,3000\n",
    )
    out_csv = tmp_path / "out.csv"
    code, out, err = run(capsys, "simulate", "--batch", str(table), "--out", str(out_csv))
    assert_one_error_line(code, out, err, "bad_rows.csv", "row 3", "column 'command'", "hop")
    assert not out_csv.exists()
    assert list(tmp_path.iterdir()) == [table]


def test_nonfinite_cell_in_batch(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    table = write(tmp_path / "nan_cell.csv", "command,phi,k\nsingle,0.6,3000\nsingle,0.6,inf\n")
    code, out, err = run(capsys, "simulate", "--batch", str(table), "--out", str(tmp_path / "o"))
    assert_one_error_line(code, out, err, "nan_cell.csv", "row 2", "column 'k'", "finite")


@pytest.fixture(scope="module")
def large_batch_text() -> str:
    """A 60,000-row batch table (all five commands, per-row settings), as CSV text."""
    rng = np.random.default_rng(11)
    n = 60_000
    table = pd.DataFrame(
        {
            "command": rng.choice(COMMAND_NAMES, n),
            "phi": rng.uniform(0.592, 0.632, n),
            "k": rng.uniform(1e3, 1e4, n),
            "c_d": rng.uniform(0, 100, n),
            "r_unload": rng.uniform(1, 50, n),
            "freq_hz": rng.choice([8.0, 10.0, 12.0], n),
            "note": rng.choice(["a", "b"], n),
        }
    )
    return table.to_csv(index=False)


@pytest.mark.parametrize(
    ("column", "value", "fragment"),
    [
        ("c_d", "1_000", "expected a number, got '1_000'"),
        ("k", "inf", "expected a finite number, got 'inf'"),
        ("phi", "", "empty cell, expected a number"),
        ("r_unload", "0.5", "got '0.5', must be >= 1"),
        ("freq_hz", "fast", "expected a number, got 'fast'"),
        ("command", "hop", "unknown command 'hop'"),
        (None, "extra", "8 fields, but the header has 7"),
    ],
)
def test_bad_cell_deep_in_a_large_batch(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    large_batch_text: str,
    column: str | None,
    value: str,
    fragment: str,
) -> None:
    """A bad cell at row 50,000 of 60,000 (a later one in an earlier column too): exit 2,
    one line naming the file, that row and column, nothing written."""
    lines = large_batch_text.splitlines()
    header = lines[0].split(",")

    def spoil(row: int, name: str | None, text: str) -> None:
        cells = lines[row].split(",")  # data row r is line r (the header is line 0)
        if name is None:
            cells.append(text)
        else:
            cells[header.index(name)] = text
        lines[row] = ",".join(cells)

    spoil(50_000, column, value)
    spoil(55_000, "command", "later")
    table = write(tmp_path / "large.csv", "\n".join(lines) + "\n")
    out_csv = tmp_path / "out.csv"
    code, out, err = run(capsys, "simulate", "--batch", str(table), "--out", str(out_csv))
    where = "large.csv, row 50000" + ("" if column is None else f", column '{column}'")
    assert_one_error_line(code, out, err, where, fragment)
    assert list(tmp_path.iterdir()) == [table]


def test_negative_mass_in_toml(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    toml = write(tmp_path / "robot.toml", "[robot]\nm_motor = 1.0\nm_foot = -0.1\n")
    code, out, err = run(capsys, *ONE_JUMP, "--experiment", str(toml))
    assert_one_error_line(code, out, err, "robot.toml", "row 3", "column 'robot.m_foot'", "-0.1")


def test_malformed_toml(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write(tmp_path / "experiment.toml", "[robot\nm_motor = 1.0\n")
    code, out, err = run(capsys, *ONE_JUMP, "--experiment", str(tmp_path), "--json")
    assert_one_error_line(code, out, err, "experiment.toml", "row 1", "malformed TOML")


def test_malformed_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    table = write(tmp_path / "quotes.csv", 'command,phi,k\nsingle,0.6,3000\n"single,0.6,3000\n')
    code, out, err = run(capsys, "simulate", "--batch", str(table), "--out", str(tmp_path / "o"))
    assert_one_error_line(code, out, err, "quotes.csv", "malformed CSV")


@pytest.mark.parametrize(
    ("argv", "fragments"),
    [
        (["--param", "q=1"], ["--param q=1", "unknown force parameter 'q'"]),
        (["--param", "cd=1"], ["--param cd=1", "did you mean 'c_d'"]),
        (["--param", "c_d=-1"], ["--param c_d=-1: c_d must be >= 0 [kg/m], got -1"]),
        (["--param", "c_d=nan"], ["--param c_d=nan", "finite"]),
        (["--param", "c_d"], ["--param c_d", "NAME=VALUE"]),
        (["--param", "c_d=fast"], ["--param c_d=fast", "must be a number"]),
        (["--param", "k=1"], ["--param k=1", "more than once"]),
    ],
)
def test_bad_param(
    argv: list[str], fragments: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, *ONE_JUMP, *argv)
    assert_one_error_line(code, out, err, *fragments)


@pytest.mark.parametrize(
    ("argv", "fragments"),
    [
        (["simulate", "--command", "single", "--phi", "0.6"], ["--param k=VALUE is required"]),
        (["simulate", "--command", "hop", "--phi", "0.6", "--param", "k=1"], ["--command hop"]),
        (["simulate", "--command", "single", "--phi", "1.5", "--param", "k=1"], ["--phi 1.5"]),
        (["simulate", "--command", "single", "--phi", "inf", "--param", "k=1"], ["--phi inf"]),
        (["simulate", "--phi", "0.6", "--param", "k=1"], ["--command is required"]),
        (["simulate", "--command", "single", "--param", "k=1", "--out", "x"], ["--out"]),
        (["simulate", "--batch", "in.csv"], ["--batch needs --out"]),
        (["simulate", "--batch", "in.csv", "--out", "o.csv", "--json"], ["--json"]),
        (["simulate", "--nonsense"], ["unrecognized arguments: --nonsense"]),
        (["frobnicate"], ["invalid choice: 'frobnicate'"]),
        (["diagnose", "d", "--calibration", "pool"], ["--calibration", "invalid choice: 'pool'"]),
        ([], ["required"]),
    ],
)
def test_bad_usage(
    argv: list[str], fragments: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, *argv)
    assert_one_error_line(code, out, err, *fragments)


def test_missing_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nowhere"
    code, out, err = run(capsys, *ONE_JUMP, "--experiment", str(missing))
    assert_one_error_line(code, out, err, str(missing), "no such file")
    code, out, err = run(capsys, *ONE_JUMP, "--trajectory", str(missing / "t.csv"))
    assert_one_error_line(code, out, err, "--trajectory", "does not exist")
    code, out, err = run(
        capsys, "simulate", "--batch", str(missing), "--out", str(tmp_path / "o.csv")
    )
    assert_one_error_line(code, out, err, str(missing))
    assert list(tmp_path.iterdir()) == []


def test_failed_batch_leaves_existing_out_untouched(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out_csv = write(tmp_path / "out.csv", "command,phi,height_mm,status\nsingle,0.6,1.0,ok\n")
    before = out_csv.read_bytes()
    table = write(tmp_path / "in.csv", "command,phi,k\nsingle,0.6,3000\nsingle,2.0,3000\n")
    code, out, err = run(capsys, "simulate", "--batch", str(table), "--out", str(out_csv))
    assert_one_error_line(code, out, err, "in.csv", "row 2", "column 'phi'")
    assert out_csv.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.csv", "out.csv"]


def test_atomic_path_failure_keeps_old_file(tmp_path: Path) -> None:
    target = write(tmp_path / "out.csv", "old contents\n")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half a fi")
        raise RuntimeError("disk full")
    assert target.read_text() == "old contents\n"
    assert list(tmp_path.iterdir()) == [target]
    with atomic_path(target) as tmp:
        tmp.write_text("new contents\n")
    assert target.read_text() == "new contents\n"
    assert list(tmp_path.iterdir()) == [target]


# ----------------------------------------------------------------------------------------
# The installed program
# ----------------------------------------------------------------------------------------


def test_console_script(tmp_path: Path) -> None:
    program = granbayes_program()
    done = subprocess.run(
        [*program, *ONE_JUMP, "--param", "c_d=50", "--json"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == EXIT_OK, done.stderr
    record = json.loads(done.stdout)
    expected = simulate("single", 0.612, {"k": 3000.0, "c_d": 50.0})
    assert record["height_mm"] == pytest.approx(float(expected.height_mm[0]), abs=1e-9)

    bad = write(tmp_path / "bad.csv", "command,phi,k\nsingle,0.6,1\nsingle,0.6,1\nleap,0.6,1\n")
    done = subprocess.run(
        [*program, "simulate", "--batch", str(bad), "--out", str(tmp_path / "out.csv")],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == EXIT_INPUT
    assert done.stdout == ""
    assert re.fullmatch(
        r"granbayes: error: .*bad\.csv, row 3, column 'command': unknown command 'leap'.*\n",
        done.stderr,
    )


# ----------------------------------------------------------------------------------------
# Demo
# ----------------------------------------------------------------------------------------


def test_demo_quiet_prints_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--quiet`` keeps the files and prints nothing."""
    code, out, err = run(capsys, "demo", "--out", str(tmp_path / "d"), "--no-fit", "--quiet")
    assert code == EXIT_OK, err
    assert out == ""
    assert (tmp_path / "d" / "heights.csv").exists()


def test_demo_writes_its_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out_dir = tmp_path / "demo"
    code, out, err = run(capsys, "demo", "--out", str(out_dir), "--no-fit")
    assert code == EXIT_OK, err
    for name in ("jumps.png", "hard_ground.png"):
        assert (out_dir / name).read_bytes()[:8] == PNG_MAGIC
    heights = pd.read_csv(out_dir / "heights.csv")
    assert list(heights["command"]) == list(COMMAND_NAMES)
    assert (heights["status"] == "ok").all()
    for row in heights.itertuples():
        assert f"{row.height_mm:.2f}" in out  # the printed table
    hard = pd.read_csv(out_dir / "hard_ground.csv")
    single = hard[hard["command"] == "single"].set_index("freq_hz")["height_mm"]
    stutter = hard[hard["command"] == "stutter"].set_index("freq_hz")["height_mm"]
    f0 = 11.03  # sqrt(5760 / 1.2) / (2 pi): single optimum above it, stutter below
    assert single.idxmax() > f0 > stutter.idxmax()
    # the demo heights.csv is itself a valid batch input
    code, _, _ = run(
        capsys,
        "simulate",
        "--batch",
        str(out_dir / "heights.csv"),
        "--out",
        str(tmp_path / "again.csv"),
    )
    assert code == EXIT_OK
    again = pd.read_csv(tmp_path / "again.csv")
    np.testing.assert_allclose(again["height_mm"], heights["height_mm"])


# ----------------------------------------------------------------------------------------
# Inference: exit codes, --quiet, the sampler options, progress bars
# ----------------------------------------------------------------------------------------

#: A fit capped at 100 steps: too short for the default stopping rule (ESS >= 400 over two
#: ensembles of 8 walkers), so it does not converge.
CAPPED_FIT = ["--terms", "depth", "--seed", "1", "--walkers", "8", "--ensembles", "2"]
CAPPED_FIT += ["--max-steps", "100", "--threads", "1"]


@pytest.fixture(scope="module")
def small_experiment(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """SYNTHETIC experiment folder: depth-only law, phi 0.612, three commands x 3 trials."""
    jumps = synthetic_jumps(
        {"k": 4000.0},
        3.0,
        seed=5,
        commands=("single", "preload", "delayed_stutter"),
        label="tests/test_cli.py",
    )
    return write_experiment(tmp_path_factory.mktemp("cli") / "exp", jumps, Experiment())


def test_fit_unconverged_exits_4_and_writes_everything(
    small_experiment: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An unconverged fit exits 4 (``EXIT_UNCONVERGED``) after writing all its results.

    With ``--quiet`` nothing goes to stdout; stderr has the warnings (one line each) and
    one error line. The report says the run did not converge and shows the sampler's
    R-hat across ensembles and ESS, per run and per parameter.
    """
    out = tmp_path / "OUT"
    code, stdout, err = run(
        capsys, "fit", str(small_experiment), "--out", str(out), *CAPPED_FIT, "--quiet"
    )
    assert code == EXIT_UNCONVERGED == 4
    assert stdout == ""
    lines = err.splitlines()
    assert lines[-1].startswith("granbayes: error: a sampler run did not converge")
    assert "--allow-unconverged" in lines[-1]
    assert len(lines) >= 2
    assert all(line.startswith("granbayes: warning: run phi=0.612: ") for line in lines[:-1])
    for name in ("posterior.nc", "summary.md", "summary.csv", "diagnostics.csv"):
        assert (out / name).is_file(), name
    assert not out.with_name("OUT.partial").exists()
    dt = read_datatree(out / "posterior.nc")
    assert json.loads(dt.attrs["converged"]) is False
    warnings = json.loads(dt.attrs["warnings"])
    assert [f"granbayes: warning: {w}" for w in warnings] == lines[:-1]
    text = (out / "summary.md").read_text()
    assert "**Warnings**" in text
    header = next(line for line in text.splitlines() if line.startswith("| run |"))
    columns = [c.strip() for c in header.strip("|").split("|")]
    assert {"n_ensembles", "n_chains", "rhat_max", "ess_min", "converged"} <= set(columns)
    row = next(line for line in text.splitlines() if line.startswith("| phi=0.612 |"))
    cells = dict(zip(columns, (c.strip() for c in row.strip("|").split("|")), strict=True))
    assert (cells["n_ensembles"], cells["n_chains"], cells["n_steps"]) == ("2", "16", "100")
    assert cells["converged"] == "False"
    # which part of the stopping rule failed is in the table (NaN: not assessed yet)
    unmet = (
        float(cells["steps_over_tau"]) < 10.0,
        not float(cells["rhat_max"]) <= 1.01,
        not float(cells["ess_min"]) >= 400.0,
    )
    assert any(unmet)
    summary = pd.read_csv(out / "summary.csv")
    assert {"r_hat", "ess_bulk", "ess_tail"} <= set(summary.columns)
    assert "r_hat" in text and "ess_bulk" in text


def test_fit_allow_unconverged_exits_0(
    small_experiment: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--allow-unconverged``: the same unconverged fit exits 0, still warns on stderr,
    and (without ``--quiet``) prints the summary on stdout."""
    out = tmp_path / "OUT"
    code, stdout, err = run(
        capsys, "fit", str(small_experiment), "--out", str(out), *CAPPED_FIT, "--allow-unconverged"
    )
    assert code == EXIT_OK
    assert stdout == (out / "summary.md").read_text() + "\n"
    lines = err.splitlines()
    assert lines and all(line.startswith("granbayes: warning: ") for line in lines)
    assert json.loads(read_datatree(out / "posterior.nc").attrs["converged"]) is False


@pytest.mark.parametrize("subcommand", ["fit", "diagnose"])
@pytest.mark.parametrize(
    ("option", "value", "fragment"),
    [
        ("--ensembles", "1", "must be >= 2"),
        ("--ensembles", "0", "must be >= 2"),
        ("--walkers", "5", "even number >= 4"),
        ("--walkers", "2", "even number >= 4"),
        ("--max-steps", "50", "must be >= 100"),
        ("--threads", "0", "must be >= 1"),
    ],
)
def test_inference_options_refused(
    subcommand: str,
    option: str,
    value: str,
    fragment: str,
    small_experiment: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Bad sampler options of fit and diagnose: exit 2, one line naming the option, no OUT
    (a single ensemble cannot be checked for agreement with another)."""
    out = tmp_path / "OUT"
    code, stdout, err = run(
        capsys, subcommand, str(small_experiment), "--out", str(out), option, value
    )
    assert_one_error_line(code, stdout, err, f"{option} {value}", fragment)
    assert not out.exists()
    assert not out.with_name("OUT.partial").exists()


def test_inference_help_lists_the_sampler_options(capsys: pytest.CaptureFixture[str]) -> None:
    """fit and diagnose share --walkers (per ensemble), --ensembles, --quiet and
    --allow-unconverged; --progress is gone (bars are drawn when stderr is a terminal)."""
    for subcommand in ("fit", "diagnose"):
        code, stdout, _ = run(capsys, subcommand, "--help")
        assert code == EXIT_OK
        for option in ("--walkers", "--ensembles", "--quiet", "--allow-unconverged"):
            assert option in stdout, (subcommand, option)
        assert "--progress" not in stdout
        assert "per ensemble" in stdout


def test_start_option_reaches_the_sampler(
    small_experiment: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--start`` (fit, diagnose, sbc) sets where the walkers start; ``auto`` by default;
    an unknown choice is refused by the parser, naming the option and the choices."""
    from granbayes._cli import _fit_config, build_parser

    argv = ["fit", str(small_experiment), "--out", str(tmp_path / "OUT")]
    assert _fit_config(build_parser().parse_args(argv)).sampler.start == "auto"
    chosen = build_parser().parse_args([*argv, "--start", "search"])
    assert _fit_config(chosen).sampler.start == "search"
    for subcommand in ("fit", "diagnose", "sbc"):
        assert "--start" in run(capsys, subcommand, "--help")[1], subcommand
    code, _, err = run(capsys, *argv, "--start", "ball")
    assert code == EXIT_INPUT
    assert "--start" in err and "'search'" in err


def _info(step: int, converged: bool = False) -> ProgressInfo:
    return ProgressInfo(
        step=step, max_steps=1000, tau_max=12.0, rhat_max=1.004, ess_min=456.0, converged=converged
    )


def test_progress_bars_one_labelled_bar_per_run(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """On a terminal, one bar per run label, with steps, tau, R-hat, ESS and convergence;
    none with ``quiet`` or when stderr is not a terminal."""
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    with ProgressBars(quiet=False) as bars:
        assert bars.enabled
        bars("phi=0.602", _info(100))
        bars("phi=0.602", _info(200, converged=True))
        bars("phi=0.622", _info(100))
        assert sorted(bars.bars) == ["phi=0.602", "phi=0.622"]
        assert bars.bars["phi=0.602"].n == 200
        assert bars.bars["phi=0.602"].total == 200  # a converged run's bar ends there
        assert bars.bars["phi=0.622"].total == 1000
    err = capsys.readouterr().err
    assert "phi=0.602" in err and "phi=0.622" in err
    assert "rhat=1.004" in err and "ess=456" in err and "tau=12" in err
    with ProgressBars(quiet=True) as bars:
        assert not bars.enabled
        bars("phi=0.602", _info(100))
        assert bars.bars == {}
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False)
    with ProgressBars(quiet=False) as bars:
        assert not bars.enabled
        bars("phi=0.602", _info(100))
    assert capsys.readouterr().err == ""
