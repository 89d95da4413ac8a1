"""Tests of the campaign engine (``granbayes.campaign``) on real Dask clusters.

The tasks here are tiny functions of this module (shipped to the workers by value with
cloudpickle), so these tests exercise the engine, not the fits: failures recorded without
stopping the others, resume computing only what is missing, a worker killed mid-task
(its task retried elsewhere), a foreign folder refused, an unreachable scheduler refused
with nothing written. One ``LocalCluster`` of two single-threaded worker processes is
shared by the module; the worker-kill test gets its own.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cloudpickle
import pandas as pd
import pytest
from distributed import Client, LocalCluster

from granbayes.campaign import (
    CampaignError,
    ClusterSettings,
    Task,
    campaign_fingerprint,
    finished_tasks,
    local_cluster_size,
    run_campaign,
    spawn_seeds,
)

cloudpickle.register_pickle_by_value(sys.modules[__name__])


def square(x: int, *, seed: int, fail_on: int = -1, sleep_s: float = 0.05) -> list[dict]:
    """A task: ``x**2`` and the seed; raises for ``x == fail_on``."""
    time.sleep(sleep_s)
    if x == fail_on:
        raise RuntimeError(f"task {x} fails on purpose")
    return [{"x": x, "y": x * x, "seed_echo": seed, "pid": os.getpid()}]


def die_once(marker: str, x: int, *, seed: int) -> list[dict]:
    """A task whose first attempt kills its own worker process (SIGKILL) mid-task."""
    path = Path(marker)
    if not path.exists():
        path.write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return [{"x": x, "seed_echo": seed, "pid": os.getpid()}]


def tasks_of(n: int, master_seed: int = 11, **kwargs) -> list[Task]:
    seeds = spawn_seeds(master_seed, n)
    return [Task(f"t{i:02d}", square, (i,), kwargs, seed=s) for i, s in enumerate(seeds)]


def snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file below ``folder``: relative path -> (bytes, mtime in ns)."""
    return {
        str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def client() -> Iterator[Client]:
    with (
        LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0"
        ) as cluster,
        Client(cluster, set_as_default=False) as c,
    ):
        yield c


# ----------------------------------------------------------------------------------------
def test_spawned_seeds_do_not_depend_on_the_number_of_tasks() -> None:
    assert spawn_seeds(7, 3) == spawn_seeds(7, 10)[:3]
    assert len(set(spawn_seeds(7, 100))) == 100
    assert spawn_seeds(7, 3) != spawn_seeds(8, 3)
    with pytest.raises(ValueError, match="seed must be >= 0"):
        spawn_seeds(-1, 2)


def test_local_cluster_never_oversubscribes_the_cores() -> None:
    assert local_cluster_size(None, cores=2) == (2, 1)
    assert local_cluster_size(1, cores=2) == (1, 2)
    assert local_cluster_size(3, cores=8) == (3, 2)
    for workers in (1, 2, 3, 4, 8):
        n, threads = local_cluster_size(workers, cores=8)
        assert n * threads <= 8
    with pytest.raises(ValueError, match="n_workers must be >= 1"):
        local_cluster_size(0, cores=2)


def test_bad_task_ids_are_refused(tmp_path: Path) -> None:
    bad = [Task("../escape", square, (1,))]
    with pytest.raises(ValueError, match=re.escape("task_id '../escape'")):
        run_campaign(bad, tmp_path / "out", description={})
    dup = [Task("a", square, (1,)), Task("a", square, (2,))]
    with pytest.raises(ValueError, match="used more than once"):
        run_campaign(dup, tmp_path / "out", description={})
    assert not (tmp_path / "out").exists()


def test_failure_is_recorded_and_others_finish_then_resume_reruns_only_it(
    tmp_path: Path, client: Client
) -> None:
    out = tmp_path / "camp"
    tasks = tasks_of(6, fail_on=3)
    res = run_campaign(tasks, out, description={"study": "squares"}, client=client, progress=False)
    assert res.n_failed == 1 and res.n_run == 6 and res.n_reused == 0
    failed = res.tasks.set_index("task_id").loc["t03"]
    assert failed["status"] == "error"
    assert "RuntimeError: task 3 fails on purpose" in failed["error"]
    # the others finished, each exactly once, on this cluster's workers, with its own seed
    assert sorted(res.results["x"]) == [0, 1, 2, 4, 5]
    assert set(res.workers) <= set(client.scheduler_info()["workers"])
    assert list(res.results["seed_echo"]) == [t.seed for t in tasks if t.task_id != "t03"]
    assert sorted(p.name for p in (out / "tasks").iterdir()) == [f"t{i:02d}.json" for i in range(6)]
    assert not (out.with_name("camp.partial")).exists()
    record = json.loads((out / "tasks" / "t03.json").read_text())
    assert "Traceback" in record["traceback"]
    # what has finished, read back without running: the finished folder, then the same
    # files as a stopped campaign's OUT.partial
    done, results = finished_tasks(out)
    assert list(done["task_id"]) == [f"t{i:02d}" for i in range(6)]
    assert list(done["status"]) == ["ok", "ok", "ok", "error", "ok", "ok"]
    pd.testing.assert_frame_equal(results, res.results)
    stopped = tmp_path / "stopped"
    shutil.copytree(out, stopped.with_name("stopped.partial"))
    pd.testing.assert_frame_equal(finished_tasks(stopped)[1], res.results)
    with pytest.raises(CampaignError, match="no finished task"):
        finished_tasks(tmp_path / "nothing")

    before = snapshot(out / "tasks")
    res2 = run_campaign(
        tasks, out, description={"study": "squares"}, client=client, resume=True, progress=False
    )
    assert res2.n_reused == 5 and res2.n_run == 1 and res2.n_failed == 1
    after = snapshot(out / "tasks")
    assert {k: v for k, v in after.items() if k != "t03.json"} == {
        k: v for k, v in before.items() if k != "t03.json"
    }

    # extending the campaign with more tasks on resume keeps the first ones' seeds
    res3 = run_campaign(
        tasks_of(8, fail_on=3),
        out,
        description={"study": "squares"},
        client=client,
        resume=True,
        progress=False,
    )
    assert res3.n_reused == 5 and res3.n_run == 3
    assert sorted(res3.results["x"]) == [0, 1, 2, 4, 5, 6, 7]


def test_resume_of_another_campaign_is_refused_and_touches_nothing(
    tmp_path: Path, client: Client
) -> None:
    out = tmp_path / "camp"
    run_campaign(tasks_of(2), out, description={"seed": 1}, client=client, progress=False)
    before = snapshot(out)
    with pytest.raises(CampaignError, match="holds another campaign"):
        run_campaign(tasks_of(2), out, description={"seed": 2}, resume=True, progress=False)
    assert snapshot(out) == before
    # the same for an interrupted run (OUT.partial)
    partial = out.with_name("camp.partial")
    out.rename(partial)
    with pytest.raises(CampaignError, match="holds another campaign"):
        run_campaign(tasks_of(2), out, description={"seed": 2}, resume=True, progress=False)
    assert snapshot(partial) == before and not out.exists()
    # a folder that is no campaign at all
    other = tmp_path / "fit-output"
    other.mkdir()
    (other / "posterior.nc").write_text("x")
    with pytest.raises(CampaignError, match="holds no campaign"):
        run_campaign(tasks_of(2), other, description={"seed": 2}, resume=True, progress=False)


def test_fingerprint_is_order_independent() -> None:
    assert campaign_fingerprint({"a": 1, "b": [1, 2]}) == campaign_fingerprint(
        {"b": [1, 2], "a": 1}
    )
    assert campaign_fingerprint({"a": 1}) != campaign_fingerprint({"a": 2})


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_is_refused_with_nothing_written(tmp_path: Path) -> None:
    out = tmp_path / "camp"
    address = f"tcp://127.0.0.1:{_free_port()}"
    t0 = time.perf_counter()
    with pytest.raises(CampaignError, match="no Dask scheduler could be reached within 1 s"):
        run_campaign(
            tasks_of(2),
            out,
            description={},
            cluster=ClusterSettings(scheduler_address=address, connect_timeout_s=1),
        )
    assert time.perf_counter() - t0 < 30
    with pytest.raises(CampaignError, match="not a Dask address"):
        run_campaign(
            tasks_of(2),
            out,
            description={},
            cluster=ClusterSettings(scheduler_address="no-port-here"),
        )
    assert list(tmp_path.iterdir()) == []


def test_the_former_loose_cluster_keywords_are_deprecated(tmp_path: Path) -> None:
    """``scheduler_address=`` etc. still work (as ``ClusterSettings`` fields), with a warning
    that names the new form; a keyword that was never one is a TypeError."""
    with (
        pytest.warns(
            DeprecationWarning, match=r"cluster=ClusterSettings\(scheduler_address"
        ) as rec,
        pytest.raises(CampaignError, match="not a Dask address"),
    ):
        run_campaign(tasks_of(2), tmp_path / "c", description={}, scheduler_address="nowhere")
    assert rec[0].filename == __file__  # the caller's line
    with pytest.raises(TypeError, match="unexpected keyword argument 'n_worker'"):
        run_campaign(tasks_of(2), tmp_path / "c", description={}, n_worker=2)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("field", "value"), [("n_workers", 0), ("numba_threads", 0), ("connect_timeout_s", 0.0)]
)
def test_cluster_settings_refuse_what_cannot_run(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=f"ClusterSettings.{field}"):
        ClusterSettings(**{field: value})


def test_worker_killed_mid_task_is_retried_and_the_campaign_completes(tmp_path: Path) -> None:
    marker = tmp_path / "killed-worker-pid"
    seeds = spawn_seeds(5, 6)
    tasks = [Task(f"t{i}", square, (i,), {"sleep_s": 0.3}, seed=seeds[i]) for i in range(5)]
    tasks.insert(2, Task("killer", die_once, (str(marker), 99), seed=seeds[5]))
    with (
        LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0"
        ) as cluster,
        Client(cluster, set_as_default=False) as c,
    ):
        res = run_campaign(tasks, tmp_path / "camp", description={}, client=c, progress=False)
    killed_pid = int(marker.read_text())
    assert res.n_failed == 0, res.tasks[["task_id", "status", "error"]]
    rows = res.tasks.set_index("task_id")
    assert rows.loc["killer", "pid"] != killed_pid  # it ran again, in another process
    assert sorted(res.results["x"]) == [0, 1, 2, 3, 4, 99]  # nothing lost or duplicated
    assert len(list((tmp_path / "camp" / "tasks").iterdir())) == 6


_KILLED_SCRIPT = '''\
import sys
import time

from granbayes.campaign import ClusterSettings, Task, run_campaign, spawn_seeds


def slow_square(x, *, seed):
    """The test module's ``square`` with a longer sleep (the campaign is killed mid-way)."""
    time.sleep(0.4)
    return [{"x": x, "y": x * x, "seed_echo": seed}]


if __name__ == "__main__":
    seeds = spawn_seeds(7, 5)
    run_campaign(
        [Task(f"t{i}", slow_square, (i,), seed=s) for i, s in enumerate(seeds)],
        sys.argv[1],
        description={"test": "killed client"},
        cluster=ClusterSettings(n_workers=1, numba_threads=1),
        progress=False,
    )
'''


def test_a_killed_campaign_resumes_without_recomputing(
    tmp_path: Path, client: Client, kill_when_written
) -> None:
    """The process that runs a campaign (and its local cluster) is killed (SIGKILL) after
    its first results: nothing appears at OUT, the finished results stay in OUT.partial,
    and ``resume`` (here on another cluster) runs only the others, leaving the finished
    files as they were (bytes and modification times), with no half-written leftovers.
    The SBC command's own kill-and-resume test, on fits, is slow."""
    script = tmp_path / "killed.py"
    script.write_text(_KILLED_SCRIPT)
    out, partial = tmp_path / "camp", tmp_path / "camp.partial"
    kill_when_written([sys.executable, str(script), str(out)], partial / "tasks", "t*.json")
    assert not out.exists()  # OUT appears only when the campaign completes
    finished = snapshot(partial / "tasks")
    assert 1 <= len(finished) < 5

    seeds = spawn_seeds(7, 5)
    tasks = [Task(f"t{i}", square, (i,), {"sleep_s": 0.0}, seed=s) for i, s in enumerate(seeds)]
    res = run_campaign(
        tasks,
        out,
        description={"test": "killed client"},
        client=client,
        resume=True,
        progress=False,
    )
    assert res.n_reused == len(finished) and res.n_run == 5 - len(finished)
    assert res.n_failed == 0
    after = snapshot(out / "tasks")
    assert {name: after[name] for name in finished} == finished  # not recomputed, not rewritten
    assert sorted(after) == [f"t{i}.json" for i in range(5)]
    assert sorted(res.results["x"]) == [0, 1, 2, 3, 4]
    assert list(res.results["seed_echo"]) == list(seeds)
    assert not partial.exists()
    assert not list((out / "tasks").glob(".*"))  # no half-written leftovers


_COLD_SCRIPT = '''\
import sys

import numba  # the main module imports numba at its top, as the CLI and every study do

from granbayes.campaign import ClusterSettings, Task, run_campaign


def compile_fresh(x, *, seed):
    """A task that JIT-compiles a function nobody compiled before (a cold numba cache)."""

    @numba.njit
    def plus_one(v):
        return v + 1

    return [{"x": x, "y": int(plus_one(x)), "threads": numba.get_num_threads()}]


if __name__ == "__main__":
    res = run_campaign(
        [Task(f"t{i}", compile_fresh, (i,), seed=i) for i in range(2)],
        sys.argv[1],
        description={"test": "cold numba cache"},
        cluster=ClusterSettings(n_workers=1, numba_threads=1),
        progress=False,
    )
    for _, row in res.tasks.iterrows():
        print(row["task_id"], row["status"], row["error"])
    sys.exit(res.n_failed)
'''


@pytest.mark.skipif(local_cluster_size()[0] < 2, reason="needs 2 cores")
def test_tasks_that_compile_on_a_cold_numba_cache_run_on_a_local_cluster(
    tmp_path: Path,
) -> None:
    """Regression: a worker process re-imports the main module (``spawn``), so numba is
    loaded with the machine's default thread count before Dask's ``env`` reaches the
    worker; a ``NUMBA_NUM_THREADS`` given there then made every task that compiled fail
    ("Cannot set NUMBA_NUM_THREADS to a different value once the threads have been
    launched"). A user's first campaign, on a fresh install, compiles. The thread budget
    is set per task by ``numba.set_num_threads`` instead."""
    script = tmp_path / "cold_campaign.py"
    script.write_text(_COLD_SCRIPT)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_NUM_THREADS"}
    proc = subprocess.run(
        [sys.executable, str(script), str(tmp_path / "camp")],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
    rows = pd.read_csv(tmp_path / "camp" / "results.csv")
    assert sorted(rows["y"]) == [1, 2]
    assert set(rows["threads"]) == {1}  # the per-task budget holds
