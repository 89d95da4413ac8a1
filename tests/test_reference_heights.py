"""The simulator against the project's converged reference heights.

``tests/data/reference-heights.csv`` (the project's copy of ``shared/reference-heights.csv``,
checked equal to it wherever the shared contracts are: ``shared_file`` in
``tests/conftest.py``) is a batch table
(``granbayes simulate --batch`` input) with a ``height_mm`` column: one jump per row,
every command, every force term, elastic and plastic beds. Each row is its own test,
named by its row number, command and the non-zero force parameters, so a failure says
which physics broke.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from granbayes import SolverSettings, load_batch_table, simulate_table
from granbayes.forces import PARAMETER_NAMES

REFERENCE_HEIGHTS = Path(__file__).resolve().parent / "data" / "reference-heights.csv"

#: The project contract: default solver settings reproduce converged heights within this.
DEFAULT_TOLERANCE_MM = 0.05
#: Converged settings against the converged reference. The reference is quoted to 1e-4 mm;
#: an independent integration (scipy DOP853, rtol 1e-12, exact events) and the converged
#: kernel agree with each other within 2e-8 mm but both sit up to 2.6e-3 mm above the
#: quoted values (the reference's own error), so 5e-3 mm leaves a factor 2 of margin.
CONVERGED_TOLERANCE_MM = 0.005


def _row_id(index: int, row: pd.Series) -> str:
    params = ",".join(
        f"{name}={row[name]:g}"
        for name in PARAMETER_NAMES
        if name in row and pd.notna(row[name]) and row[name] != 0.0
    )
    return f"{index:02d}-{row['command']}-{params}"


def _collect() -> list:
    table = load_batch_table(REFERENCE_HEIGHTS)
    return [pytest.param(i, id=_row_id(i, row)) for i, row in table.iterrows()]


ROWS = _collect()


def test_project_copy_equals_the_shared_reference(shared_file) -> None:
    """The repository's copy is byte-identical to ``shared/reference-heights.csv``.

    Skipped (saying so) only in a clone without ``shared/``; every other test of this
    module reads the repository's copy.
    """
    assert REFERENCE_HEIGHTS.read_bytes() == shared_file("reference-heights.csv").read_bytes()


@pytest.fixture(scope="module")
def reference() -> pd.DataFrame:
    """The reference table, with ``height_mm`` as float."""
    table = load_batch_table(REFERENCE_HEIGHTS)
    table["height_mm"] = pd.to_numeric(table["height_mm"]).astype(float)
    return table


@pytest.fixture(scope="module")
def simulated_default(reference: pd.DataFrame) -> pd.DataFrame:
    """The reference table simulated with the default solver settings."""
    return simulate_table(reference.drop(columns="height_mm"))


@pytest.fixture(scope="module")
def simulated_converged(reference: pd.DataFrame) -> pd.DataFrame:
    """The reference table simulated with converged solver settings."""
    return simulate_table(reference.drop(columns="height_mm"), settings=SolverSettings.converged())


def _check_row(
    index: int, reference: pd.DataFrame, simulated: pd.DataFrame, tolerance: float
) -> None:
    row = reference.iloc[index]
    out = simulated.iloc[index]
    assert out["status"] == "ok", f"row {index} ({row['command']}): status {out['status']}"
    height, expected = float(out["height_mm"]), float(row["height_mm"])
    diff = height - expected
    assert np.isfinite(height)
    assert abs(diff) <= tolerance, (
        f"row {index} {row['command']}: simulated {height:.5f} mm, reference {expected:.4f} mm,"
        f" diff {diff:+.5f} mm exceeds {tolerance} mm"
    )


@pytest.mark.parametrize("index", ROWS)
def test_default_solver_reproduces_reference_within_contract(
    index: int, reference: pd.DataFrame, simulated_default: pd.DataFrame
) -> None:
    """Default SolverSettings reproduce each converged reference height within 0.05 mm.

    This is the project contract for the default settings (``SolverSettings`` docstring),
    checked row by row through the batch-table path (``load_batch_table`` +
    ``simulate_table``) that the CLI uses.
    """
    _check_row(index, reference, simulated_default, DEFAULT_TOLERANCE_MM)


@pytest.mark.parametrize("index", ROWS)
def test_converged_solver_reproduces_reference(
    index: int, reference: pd.DataFrame, simulated_converged: pd.DataFrame
) -> None:
    """``SolverSettings.converged()`` reproduces each reference height within 0.005 mm.

    Ten times tighter than the default contract: a wrong term, sign or event would shift a
    height by far more, while the reference's own error is below 0.003 mm.
    """
    _check_row(index, reference, simulated_converged, CONVERGED_TOLERANCE_MM)
