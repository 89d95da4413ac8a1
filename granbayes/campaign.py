"""Campaigns: many independent, deterministic tasks on a Dask cluster, resumable.

A campaign is a list of :class:`Task` (a module-level function, its arguments and a seed
spawned from one master seed by :func:`spawn_seeds`). :func:`run_campaign` runs the tasks
on a ``dask.distributed`` cluster (a ``LocalCluster`` sized to the machine by default, or
an existing scheduler by address, e.g. one started by ``dask-jobqueue`` on Slurm; see
``docs/campaigns.md``) and builds its output folder ``OUT`` as ``OUT.partial``:

``campaign.json``
    the campaign's description (data, settings, master seed) and its SHA-256
    fingerprint; resuming a folder whose fingerprint differs is refused;
``tasks/<task_id>.json``
    one file per finished task, written atomically by the driver as soon as the task
    returns: its status (``ok`` or ``error`` with the error text), the Dask worker that
    ran it, its host, pid, wall time and its result rows;
``tasks.csv``
    one row per task (status, worker, time, error);
``results.csv`` (or another name)
    the tidy table: every result row of every task, with its ``task_id`` and ``worker``.

``OUT.partial`` replaces ``OUT`` when every task has finished (successfully or not). A
killed campaign keeps ``OUT.partial``; run it again with ``resume=True`` and only the
tasks without a successful result file are computed (failed tasks are tried again).
Because every result is one file named by its task, nothing can be counted twice.

Faults: a task that raises is recorded with its error and does not stop the others (it is
not retried: tasks are deterministic). A worker that dies (killed, out of memory, node
lost) is handled by the Dask scheduler: the tasks it was running are rescheduled on other
workers, up to the ``distributed.scheduler.allowed-failures`` setting (default 3), after
which the task is recorded as failed with Dask's ``KilledWorker`` error.

CPU budget: the simulator runs on numba threads. A local cluster gets ``n_workers``
single-threaded worker processes (default: one per core) and every task runs with
``cores // n_workers`` numba threads, so workers x threads never exceeds the cores. On an
existing cluster start workers with ``--nthreads 1`` and give ``numba_threads`` (default 1).
Where a campaign runs is one object, :class:`ClusterSettings`, which every campaign of the
package takes (``run_campaign``, ``granbayes.run_sbc``, the studies of ``benchmarks/``).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import os
import re
import shutil
import socket
import time
import traceback
import uuid
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ._deprecated import outside_package
from ._files import atomic_path, jsonable, partial_folder, staged_folder, write_json

if TYPE_CHECKING:
    from distributed import Client

__all__ = [
    "ClusterSettings",
    "CampaignError",
    "CampaignResult",
    "Task",
    "campaign_fingerprint",
    "finished_tasks",
    "local_cluster_size",
    "run_campaign",
    "spawn_seeds",
]

#: Allowed task ids (they name files): a letter or digit, then letters, digits, ``_.-``.
_TASK_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")

#: Columns of ``tasks.csv``.
TASK_COLUMNS = (
    "task_id",
    "seed",
    "status",
    "worker",
    "worker_name",
    "host",
    "pid",
    "numba_threads",
    "started_utc",
    "elapsed_s",
    "n_rows",
    "error",
)


class CampaignError(ValueError):
    """A campaign that cannot start as asked (unreachable scheduler, foreign folder)."""


@dataclass(frozen=True)
class ClusterSettings:
    """Where a campaign runs: a local Dask cluster (default) or an existing scheduler.

    Parameters
    ----------
    scheduler_address : str, optional
        Address of an existing Dask scheduler (``tcp://host:port``, e.g. one started by
        ``dask-jobqueue`` on Slurm or PBS: ``docs/campaigns.md``); default: a
        ``LocalCluster`` on this machine.
    n_workers : int, optional
        Worker processes of the local cluster (default: one per core). Not used with
        ``scheduler_address`` or a client.
    numba_threads : int, optional
        numba threads per task (default: ``cores // n_workers`` on a local cluster, so
        workers x threads never exceeds the cores; 1 on an existing cluster).
    connect_timeout_s : float
        How long to try reaching ``scheduler_address`` [s].

    Raises
    ------
    ValueError
        ``n_workers`` or ``numba_threads`` below 1, a timeout that is not positive.
    """

    scheduler_address: str | None = None
    n_workers: int | None = None
    numba_threads: int | None = None
    connect_timeout_s: float = 10.0

    def __post_init__(self) -> None:
        """Refuse settings no cluster can run with."""
        for name in ("n_workers", "numba_threads"):
            value = getattr(self, name)
            if value is not None and int(value) < 1:
                raise ValueError(f"ClusterSettings.{name} = {value}: must be >= 1")
        if not float(self.connect_timeout_s) > 0:
            raise ValueError(
                f"ClusterSettings.connect_timeout_s = {self.connect_timeout_s}: must be > 0"
            )


#: The keyword arguments that ``run_campaign`` and ``run_sbc`` took before
#: :class:`ClusterSettings` (deprecated; each is the field of the same name).
_CLUSTER_KEYWORDS = frozenset(f.name for f in fields(ClusterSettings))


def cluster_settings(
    cluster: ClusterSettings | None, legacy: Mapping[str, Any], where: str
) -> ClusterSettings:
    """``cluster``, with the deprecated loose keywords of ``where`` folded in (warned).

    Parameters
    ----------
    cluster : ClusterSettings, optional
        The settings given (default: ``ClusterSettings()``).
    legacy : mapping
        Other keyword arguments the caller received; those named like a field of
        :class:`ClusterSettings` are taken (with a ``DeprecationWarning``), any other is
        an error.
    where : str
        The function's name, for the messages.

    Returns
    -------
    ClusterSettings
    """
    unknown = sorted(set(legacy) - _CLUSTER_KEYWORDS)
    if unknown:
        raise TypeError(f"{where}() got an unexpected keyword argument {unknown[0]!r}")
    cluster = ClusterSettings() if cluster is None else cluster
    if legacy:
        names = ", ".join(sorted(legacy))
        warnings.warn(
            f"{where}({names}=...) is deprecated; pass cluster=ClusterSettings({names}=...)",
            DeprecationWarning,
            stacklevel=outside_package(),  # the user's line, through run_sbc too
        )
        cluster = replace(cluster, **legacy)
    return cluster


@dataclass(frozen=True)
class Task:
    """One unit of work of a campaign.

    Parameters
    ----------
    task_id : str
        Unique name within the campaign (letters, digits, ``_.-``); names its result file.
    fn : callable
        ``fn(*args, seed=seed, **kwargs) -> sequence of mappings`` (the task's result
        rows, JSON-able values). Must be deterministic given its arguments and seed, and
        importable by the workers (a module-level function of an installed package).
    args : tuple
        Positional arguments (picklable).
    kwargs : mapping
        Keyword arguments (picklable).
    seed : int
        The task's seed (from :func:`spawn_seeds`), passed as ``seed=``.
    """

    task_id: str
    fn: Callable[..., Sequence[Mapping[str, Any]]]
    args: tuple = ()
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    seed: int = 0


@dataclass
class CampaignResult:
    """A finished campaign.

    Attributes
    ----------
    folder : Path
        The output folder.
    fingerprint : str
        SHA-256 of the campaign's description.
    tasks : pandas.DataFrame
        One row per task (:data:`TASK_COLUMNS`).
    results : pandas.DataFrame
        The tidy table: every result row with ``task_id`` and ``worker``.
    n_reused : int
        Tasks whose result was already in the folder (not recomputed).
    n_run : int
        Tasks computed by this call.
    wall_time_s : float
        Wall time of this call [s] (connection and gathering included).
    """

    folder: Path
    fingerprint: str
    tasks: pd.DataFrame
    results: pd.DataFrame
    n_reused: int
    n_run: int
    wall_time_s: float

    @property
    def n_failed(self) -> int:
        """Number of tasks whose status is not ``ok``."""
        return int((self.tasks["status"] != "ok").sum()) if len(self.tasks) else 0

    @property
    def workers(self) -> list[str]:
        """Addresses of the workers that ran the tasks (sorted)."""
        return sorted({w for w in self.tasks["worker"].dropna() if w})


# ----------------------------------------------------------------------------------------
# Seeds, sizing, fingerprints
# ----------------------------------------------------------------------------------------
def spawn_seeds(master_seed: int, n: int) -> list[int]:
    """Per-task seeds spawned from one master seed (``numpy.random.SeedSequence.spawn``).

    The ``i``-th seed depends only on ``master_seed`` and ``i``, not on ``n``: a campaign
    extended with more tasks keeps the seeds of the first ones.

    Parameters
    ----------
    master_seed : int
        Non-negative master seed.
    n : int
        Number of seeds.

    Returns
    -------
    list of int
        63-bit non-negative integers.
    """
    if int(master_seed) < 0:
        raise ValueError(f"seed must be >= 0, got {master_seed}")
    children = np.random.SeedSequence(int(master_seed)).spawn(int(n))
    return [int(c.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1)) for c in children]


def local_cluster_size(n_workers: int | None = None, cores: int | None = None) -> tuple[int, int]:
    """Workers of a local cluster and numba threads per task, without oversubscription.

    Parameters
    ----------
    n_workers : int, optional
        Worker processes (default: one per core).
    cores : int, optional
        Cores to use (default: those this process may run on).

    Returns
    -------
    n_workers : int
    numba_threads : int
        ``max(1, cores // n_workers)``.
    """
    if cores is None:
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # not on Linux
            cores = os.cpu_count() or 1
    workers = cores if n_workers is None else int(n_workers)
    if workers < 1:
        raise ValueError(f"n_workers must be >= 1, got {n_workers}")
    return workers, max(1, cores // workers)


def campaign_fingerprint(description: Mapping[str, Any]) -> str:
    """SHA-256 of a campaign's description (canonical JSON, sorted keys).

    Parameters
    ----------
    description : mapping
        What identifies the campaign (JSON-able values).

    Returns
    -------
    str
        Hexadecimal digest.
    """
    text = json.dumps(description, sort_keys=True, default=str, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


# ----------------------------------------------------------------------------------------
# What runs on a worker
# ----------------------------------------------------------------------------------------
def _execute(
    fn: Callable[..., Sequence[Mapping[str, Any]]],
    args: tuple,
    kwargs: Mapping[str, Any],
    task_id: str,
    seed: int,
    numba_threads: int | None,
) -> dict[str, Any]:
    """Run one task on a worker and return its record (never raises for task errors)."""
    try:
        from distributed import get_worker

        worker = get_worker()
        address, name = str(worker.address), str(worker.name)
    except (ImportError, ValueError):  # not inside a Dask worker
        address, name = None, None
    if numba_threads is not None:
        import numba

        numba.set_num_threads(max(1, min(int(numba_threads), numba.config.NUMBA_NUM_THREADS)))
    started = _dt.datetime.now(_dt.UTC)
    t0 = time.perf_counter()
    record: dict[str, Any] = {"task_id": task_id, "seed": int(seed)}
    try:
        rows = [jsonable(dict(r)) for r in fn(*args, seed=seed, **dict(kwargs))]
        record.update(status="ok", error=None, traceback=None, rows=rows)
    except Exception as exc:
        record.update(
            status="error",
            error=f"{type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(),
            rows=[],
        )
    record.update(
        worker=address,
        worker_name=name,
        host=socket.gethostname(),
        pid=os.getpid(),
        numba_threads=numba_threads,
        started_utc=started.isoformat(timespec="seconds"),
        elapsed_s=round(time.perf_counter() - t0, 4),
    )
    return record


def _lost_record(task: Task, exc: BaseException) -> dict[str, Any]:
    """The record of a task whose future failed outside the task (e.g. KilledWorker)."""
    return {
        "task_id": task.task_id,
        "seed": int(task.seed),
        "status": "error",
        "error": f"{type(exc).__name__}: {exc}",
        "traceback": None,
        "rows": [],
        "worker": None,
        "worker_name": None,
        "host": None,
        "pid": None,
        "numba_threads": None,
        "started_utc": None,
        "elapsed_s": None,
    }


# ----------------------------------------------------------------------------------------
# Cluster connection
# ----------------------------------------------------------------------------------------
@contextlib.contextmanager
def _connect(cluster: ClusterSettings) -> Iterator[tuple[Client, int]]:
    """A Dask client (and the numba threads per task), closed on exit."""
    from distributed import Client, LocalCluster

    scheduler_address, numba_threads = cluster.scheduler_address, cluster.numba_threads
    connect_timeout_s = cluster.connect_timeout_s

    if scheduler_address is not None:
        from distributed.comm.addressing import parse_address, parse_host_port

        try:
            parse_host_port(parse_address(str(scheduler_address))[1])
        except (ValueError, TypeError) as exc:
            raise CampaignError(
                f"scheduler_address {scheduler_address!r}: not a Dask address "
                f"like tcp://host:port ({exc})"
            ) from None
        try:
            client = Client(
                scheduler_address, timeout=f"{connect_timeout_s}s", set_as_default=False
            )
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            reason = " ".join(str(exc).split()) or type(exc).__name__
            raise CampaignError(
                f"scheduler_address {scheduler_address!r}: no Dask scheduler could be reached "
                f"within {connect_timeout_s:g} s ({reason})"
            ) from None
        with client:
            yield client, (1 if numba_threads is None else int(numba_threads))
        return
    workers, threads = local_cluster_size(cluster.n_workers)
    threads = threads if numba_threads is None else int(numba_threads)
    # No NUMBA_NUM_THREADS in the workers' environment: a worker process re-imports the
    # main module (multiprocessing "spawn"), so numba is loaded with the machine's default
    # before Dask's ``env`` is applied, and every later JIT compilation (a cold cache, a
    # user's first campaign) would fail on the changed value. ``_execute`` sets the budget
    # per task with ``numba.set_num_threads``; Dask's ``pre-spawn-environ`` already keeps
    # the BLAS libraries single-threaded.
    with (
        LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address="127.0.0.1:0",
        ) as cluster,
        Client(cluster, set_as_default=False) as client,
    ):
        yield client, threads


# ----------------------------------------------------------------------------------------
# The output folder
# ----------------------------------------------------------------------------------------
def _stored_fingerprint(folder: Path) -> str | None:
    """The fingerprint in ``folder/campaign.json`` (None if the file is missing)."""
    meta = folder / "campaign.json"
    if not meta.is_file():
        return None
    try:
        return str(json.loads(meta.read_text(encoding="utf-8"))["fingerprint"])
    except (ValueError, KeyError, TypeError):
        return ""


def _check_resume(out: Path, fingerprint: str) -> Path | None:
    """Refuse to resume a folder of another campaign; return a finished folder to reuse.

    Returns
    -------
    Path or None
        ``out`` if there is no ``OUT.partial`` but ``out`` holds a finished run of this
        campaign (its results are copied into the new work folder), else None.
    """
    work = partial_folder(out)
    folder = work if work.exists() else out
    if not folder.exists():
        return None
    stored = _stored_fingerprint(folder)
    if stored is None:
        if folder == work and not (work / "tasks").exists():
            return None  # killed before its first task finished
        if folder == out and not any(out.iterdir()):
            return None
        raise CampaignError(
            f"resume: {folder} holds no campaign (no campaign.json); choose another "
            "output folder or start without resume"
        )
    if stored != fingerprint:
        raise CampaignError(
            f"resume: {folder} holds another campaign (other data, settings or seed; "
            f"fingerprint {stored[:12] or 'unreadable'} != {fingerprint[:12]}); resume it "
            "with the settings it was started with, or start this campaign in another "
            "folder or without resume"
        )
    return out if folder == out else None


def _finished(path: Path, task: Task) -> bool:
    """Whether ``path`` holds a successful result of exactly this task."""
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return (
        record.get("status") == "ok"
        and record.get("task_id") == task.task_id
        and record.get("seed") == int(task.seed)
    )


def _tables(records: Sequence[Mapping[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The task table (:data:`TASK_COLUMNS`) and the tidy results of task records."""
    task_rows = [{c: r.get(c) for c in TASK_COLUMNS if c != "n_rows"} for r in records]
    for row, r in zip(task_rows, records, strict=True):
        row["n_rows"] = len(r.get("rows") or [])
    task_table = pd.DataFrame(task_rows, columns=list(TASK_COLUMNS))
    result_rows = [
        {"task_id": r["task_id"], **row, "worker": r.get("worker")}
        for r in records
        for row in (r.get("rows") or [])
    ]
    return task_table, pd.DataFrame(result_rows)


def finished_tasks(out: str | Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """What a campaign has finished so far, whether it is running, stopped or done.

    Reads the task files of ``OUT.partial`` (a campaign under way or stopped, which holds
    every result of a resumed one) or, if there is none, of ``OUT``, without running
    anything: a stopped study can be summarised from the tasks that finished, and says how
    many did.

    Parameters
    ----------
    out : str or Path
        The campaign's output folder, as given to :func:`run_campaign`.

    Returns
    -------
    tasks : pandas.DataFrame
        One row per task file (:data:`TASK_COLUMNS`; failed tasks too, by ``status``).
    results : pandas.DataFrame
        The rows of the successful tasks, with ``task_id`` and ``worker``
        (:attr:`CampaignResult.results`).

    Raises
    ------
    CampaignError
        When neither folder holds task files.
    """
    out = Path(out)
    work = partial_folder(out)
    folder = work if work.exists() else out
    paths = sorted((folder / "tasks").glob("*.json"))
    if not paths:
        raise CampaignError(f"{folder}: no finished task (no tasks/*.json)")
    return _tables([json.loads(path.read_text(encoding="utf-8")) for path in paths])


def _gather(
    tasks_dir: Path, tasks: Sequence[Task], work: Path, results_name: str
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Read every task file and write ``tasks.csv`` and the tidy results table."""
    records = [
        json.loads((tasks_dir / f"{t.task_id}.json").read_text(encoding="utf-8")) for t in tasks
    ]
    task_table, results = _tables(records)
    with atomic_path(work / "tasks.csv") as tmp:
        task_table.to_csv(tmp, index=False)
    with atomic_path(work / results_name) as tmp:
        results.to_csv(tmp, index=False)
    return task_table, results


# ----------------------------------------------------------------------------------------
# The engine
# ----------------------------------------------------------------------------------------
def run_campaign(
    tasks: Sequence[Task],
    out: str | Path,
    *,
    description: Mapping[str, Any],
    cluster: ClusterSettings | None = None,
    client: Client | None = None,
    resume: bool = False,
    progress: bool = True,
    results_name: str = "results.csv",
    finalize: Callable[[Path, CampaignResult], None] | None = None,
    log: Callable[[str], None] | None = None,
    **deprecated: Any,
) -> CampaignResult:
    """Run every task on a Dask cluster; write each result atomically; gather a table.

    Parameters
    ----------
    tasks : sequence of Task
        The campaign (unique ``task_id``).
    out : str or Path
        Output folder (built as ``OUT.partial``, which replaces ``OUT`` at the end).
    description : mapping
        JSON-able description of what makes this campaign (data hash, settings, master
        seed). Its SHA-256 is the campaign's fingerprint; resuming a folder made with
        another one is refused. Leave the number of tasks out of it to allow extending a
        campaign on resume.
    cluster : ClusterSettings, optional
        Where to run (default: a local cluster sized to the machine).
    client : distributed.Client, optional
        An already connected client (takes precedence over ``cluster``'s scheduler and
        workers; its ``numba_threads`` still applies, default 1).
    resume : bool
        Keep the results already in ``OUT.partial`` (or in a finished ``OUT`` of the same
        campaign) and compute only the missing or failed tasks.
    progress : bool
        Show one progress bar over the tasks (stderr).
    results_name : str
        File name of the tidy results table.
    finalize : callable, optional
        ``finalize(work_folder, result)``: writes further outputs (summaries, figures) into
        the work folder before it replaces ``out``.
    log : callable, optional
        Receives one-line progress messages.
    **deprecated
        ``scheduler_address``, ``n_workers``, ``numba_threads``, ``connect_timeout_s``:
        the former loose form of ``cluster`` (``DeprecationWarning``).

    Returns
    -------
    CampaignResult

    Raises
    ------
    CampaignError
        Unreachable scheduler, or ``resume`` on a folder of another campaign; nothing is
        written then.
    ValueError
        Duplicate or malformed task ids, ``n_workers < 1``.
    """
    t_start = time.perf_counter()
    cluster = cluster_settings(cluster, deprecated, "run_campaign")
    out = Path(out)
    say = log or (lambda _msg: None)
    ids = [t.task_id for t in tasks]
    bad = [i for i in ids if not _TASK_ID.match(i)]
    if bad:
        raise ValueError(f"task_id {bad[0]!r}: use letters, digits, '_', '.', '-' only")
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise ValueError(f"task_id {dup!r} is used more than once")
    if out.exists() and not out.is_dir():
        raise ValueError(f"out {out}: exists and is not a folder")
    fingerprint = campaign_fingerprint(description)
    reuse = _check_resume(out, fingerprint) if resume else None

    with contextlib.ExitStack() as stack:
        if client is None:
            client, threads = stack.enter_context(_connect(cluster))
        else:
            threads = 1 if cluster.numba_threads is None else int(cluster.numba_threads)
        work = stack.enter_context(staged_folder(out, resume))
        tasks_dir = work / "tasks"
        if reuse is not None and not tasks_dir.exists():
            shutil.copytree(reuse / "tasks", tasks_dir)
        tasks_dir.mkdir(exist_ok=True)
        for stale in tasks_dir.glob(".*.tmp"):  # left by a process killed mid-write
            stale.unlink(missing_ok=True)
        write_json(
            work / "campaign.json",
            {
                "fingerprint": fingerprint,
                "description": jsonable(json.loads(json.dumps(description, default=str))),
                "n_tasks": len(tasks),
            },
        )
        done = {t.task_id for t in tasks if _finished(tasks_dir / f"{t.task_id}.json", t)}
        todo = [t for t in tasks if t.task_id not in done]
        n_workers_now = len(client.scheduler_info().get("workers", {}))
        say(
            f"campaign {fingerprint[:12]}: {len(tasks)} tasks, {len(done)} already done, "
            f"{len(todo)} to run on {n_workers_now} Dask worker(s) at "
            f"{client.scheduler_info().get('address')} ({threads} numba thread(s) per task)"
        )
        _run_tasks(client, todo, tasks_dir, threads, fingerprint, len(tasks), len(done), progress)
        task_table, results = _gather(tasks_dir, tasks, work, results_name)
        result = CampaignResult(
            folder=work,
            fingerprint=fingerprint,
            tasks=task_table,
            results=results,
            n_reused=len(done),
            n_run=len(todo),
            wall_time_s=time.perf_counter() - t_start,
        )
        if finalize is not None:
            finalize(work, result)
    result.folder = out
    result.wall_time_s = time.perf_counter() - t_start
    return result


def _run_tasks(
    client: Client,
    todo: Sequence[Task],
    tasks_dir: Path,
    threads: int,
    fingerprint: str,
    n_total: int,
    n_done: int,
    progress: bool,
) -> None:
    """Submit ``todo`` and write each record as its future completes."""
    from distributed import as_completed
    from tqdm.auto import tqdm

    if not todo:
        return
    token = uuid.uuid4().hex[:8]  # keys unique on a shared scheduler (no effect on results)
    futures = {
        client.submit(
            _execute,
            t.fn,
            t.args,
            dict(t.kwargs),
            t.task_id,
            int(t.seed),
            threads,
            key=f"granbayes-{t.task_id}-{fingerprint[:8]}-{token}",
        ): t
        for t in todo
    }
    failed = 0
    with tqdm(
        total=n_total, initial=n_done, disable=not progress, unit="task", desc="campaign"
    ) as bar:
        for future in as_completed(futures, loop=client.loop):
            task = futures[future]
            try:
                record = future.result()
            except Exception as exc:  # the task never returned (e.g. KilledWorker)
                record = _lost_record(task, exc)
            failed += record["status"] != "ok"
            write_json(tasks_dir / f"{task.task_id}.json", record)
            future.release()
            bar.update(1)
            if failed:
                bar.set_postfix(failed=failed)
