"""The benchmark and study scripts of ``benchmarks/`` still load against the package.

They run for minutes to hours and are not part of the suite, so a refactor of the package
that moves a name they import (or wrap) would otherwise go unnoticed until someone reruns
them: ``bench_batch.py``'s phase clock once wrapped a CSV reader in a module it had left.
Here every script is imported (its top level only; each runs its work under
``if __name__ == "__main__"``) and the batch benchmark's phase clock is entered, which looks
up every function it times.
"""

from __future__ import annotations

import importlib
import math
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
SCRIPTS = sorted(p.stem for p in BENCHMARKS.glob("*.py"))


@pytest.fixture()
def benchmarks_on_path(monkeypatch):
    """The scripts import their helpers (``_studies``, ``_machine``) from their folder."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    yield
    for name in SCRIPTS:
        sys.modules.pop(name, None)


def test_every_benchmark_script_is_found() -> None:
    assert "bench_batch" in SCRIPTS and "calibrate_verdicts" in SCRIPTS
    assert len(SCRIPTS) >= 20


@pytest.mark.parametrize("name", SCRIPTS)
def test_a_benchmark_script_imports(name, benchmarks_on_path) -> None:
    module = importlib.import_module(name)
    if not name.startswith("_"):  # a script, not a helper: it runs from its main guard
        assert "__main__" in (BENCHMARKS / f"{name}.py").read_text(encoding="utf-8")
        assert callable(getattr(module, "main", None)), f"{name}.py has no main()"


def test_the_batch_benchmarks_phase_clock_finds_what_it_times(benchmarks_on_path) -> None:
    """Every function the clock wraps exists, and leaving it restores the originals."""
    bench_batch = importlib.import_module("bench_batch")
    import granbayes._simulator

    original = granbayes._simulator.simulate_rows
    phases: dict[str, float] = {}
    with bench_batch.phase_clock(phases):
        assert granbayes._simulator.simulate_rows is not original
    assert granbayes._simulator.simulate_rows is original


def test_the_machine_record_of_the_timing_benchmarks(benchmarks_on_path) -> None:
    machine = importlib.import_module("_machine")
    info = machine.machine_info(("numpy", "pandas"))
    assert info["cpu_count"] >= 1 and info["numpy"] and info["pandas"] and info["granbayes"]
    lines = machine.machine_markdown(info)
    assert lines[0] == "## Machine" and f"- cpu: {info['cpu']}" in lines


def test_the_tracked_power_study_pairs_each_case_with_its_heights_only_twin(
    benchmarks_on_path,
) -> None:
    """Counts per kind and size, the discordant pairs and McNemar's exact test, on rows of
    the committed heights-only study with some verdicts changed; a pair whose scatter
    differs (not the same draw) is refused."""
    import pandas as pd

    power = importlib.import_module("power_curves")
    heights = pd.read_csv(BENCHMARKS / "results" / "power" / "results.csv")
    heights = heights[heights["kind"] == "drag"].reset_index(drop=True)
    was = power.detected(heights).to_numpy()
    assert was.any() and not was.all()
    tracked = heights.copy()
    # the frames find every missed case of the two largest sizes, and miss one found case
    big = tracked["size"] >= sorted(tracked["size"].unique())[-2]
    gained = big & ~was
    tracked.loc[gained, ["verdict", "added"]] = ["extended", "drag"]
    lost = int(next(i for i in range(len(was)) if was[i] and not big[i]))
    tracked.loc[lost, ["verdict", "added"]] = ["baseline_adequate", ""]
    paired = power.paired_runs(tracked, heights)
    total = paired[paired["size"].isna()].iloc[0]
    assert total["pairs"] == len(heights)
    assert total["detected_heights"] == was.sum()
    assert total["only_tracked"] == gained.sum() and total["only_heights"] == 1
    assert total["detected_tracked"] == was.sum() + gained.sum() - 1
    n = int(gained.sum()) + 1
    expected = min(1.0, 2 * sum(math.comb(n, k) for k in range(0, 2)) / 2**n)
    assert total["mcnemar_p"] == pytest.approx(expected, rel=1e-12)
    per_size = paired[paired["size"].notna()]
    assert per_size["pairs"].sum() == len(heights)
    assert per_size["mcnemar_p"].isna().all()
    tracked.loc[0, "sigma_mm"] += 0.1
    with pytest.raises(ValueError, match="not the same draw"):
        power.paired_runs(tracked, heights)


def test_the_null_arm_of_the_power_study(benchmarks_on_path, tmp_path) -> None:
    """Its tasks are null cases with seeds apart from every kind's; its summary counts
    the terms named and the misfits left, with exact intervals; a null case with a size
    is refused."""
    import json

    import pandas as pd

    power = importlib.import_module("power_curves")
    todo = power.null_tasks(3, 5, tracked=True)
    assert [t.task_id for t in todo] == ["null-000", "null-001", "null-002"]
    assert all(t.args == ("null", 0.0, i) for i, t in enumerate(todo))
    assert all(t.kwargs == {"tracking": power.POWER_TRACKING} for t in todo)
    effect_seeds = {t.seed for t in power.tasks(list(power.POWER_SIZES), 3, 5)}
    assert not effect_seeds & {t.seed for t in todo}
    with pytest.raises(ValueError, match="size is 0"):
        power.power_case("null", 1.0, 0, seed=1)
    rows = pd.read_csv(BENCHMARKS / "results" / "power" / "results.csv").head(4).copy()
    rows["verdict"] = ["baseline_adequate", "extended", "misfit_remains", "baseline_adequate"]
    rows["added"] = ["", "drag", "", ""]
    power.write_null_summary(tmp_path, rows, 5, 10, tracked=False)
    doc = json.loads((tmp_path / "summary.json").read_text())
    assert doc["false_discovery"]["count"] == 1 and doc["false_alarm"]["count"] == 1
    assert doc["false_discovery"]["lo"] == pytest.approx(0.00631, abs=1e-5)  # 1 of 4
    assert doc["false_discovery"]["hi"] == pytest.approx(0.80588, abs=1e-5)
    text = (tmp_path / "summary.md").read_text()
    assert "a stopped study: 4 of 10" in text and "1 of 4" in text


def test_a_rerun_of_the_power_study_is_compared_case_by_case(benchmarks_on_path, tmp_path) -> None:
    """``--against``: the summary pairs each case with its twin of an earlier run (the
    committed study's drag rows, two of them turned), with the discordant pairs per kind."""
    import json

    import pandas as pd

    power = importlib.import_module("power_curves")
    earlier = pd.read_csv(BENCHMARKS / "results" / "power" / "results.csv")
    earlier = earlier[earlier["kind"] == "drag"].reset_index(drop=True)
    was = power.detected(earlier).to_numpy()
    rerun = earlier.copy()
    found, missed = int(was.argmax()), int((~was).argmax())
    rerun.loc[found, ["verdict", "added"]] = ["baseline_adequate", ""]
    rerun.loc[missed, ["verdict", "added"]] = ["extended", "drag"]
    csv = tmp_path / "earlier.csv"
    earlier.to_csv(csv, index=False)
    power.write_summary(tmp_path, rerun, 5, len(rerun), against=csv)
    doc = json.loads((tmp_path / "summary.json").read_text())
    total = next(r for r in doc["paired_with_earlier"] if math.isnan(r["size"]))
    assert total["pairs"] == len(earlier)
    assert total["detected_before"] == total["detected_after"] == was.sum()
    assert total["only_after"] == total["only_before"] == 1
    assert total["mcnemar_p"] == pytest.approx(1.0)
    assert "Against an earlier run of the study" in (tmp_path / "summary.md").read_text()
