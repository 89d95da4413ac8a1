"""docs/tutorial.py (a jupytext percent-format notebook, plain Python) runs end to end."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.py"


@pytest.mark.long
def test_tutorial_runs(tmp_path: Path) -> None:
    """The tutorial runs as a script in a fresh folder and finds the hidden compaction."""
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.run(
        [sys.executable, str(TUTORIAL)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=1200,
        env=env,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = tmp_path / "tutorial-output"
    for name in ("prior_posterior.png", "loo_pit.png", "my-lab/jumps.csv"):
        assert (out / name).stat().st_size > 0, name
    assert "synthetic" in (out / "my-lab" / "jumps.csv").read_text()
    assert "verdict: extended" in proc.stdout
    assert "added: ['compaction']" in proc.stdout
