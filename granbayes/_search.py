"""Batched local searches: many independent problems, one function call per round (private).

Screening the candidate terms of ``diagnose`` runs a local search per candidate and volume
fraction; each evaluation is a batch of jump simulations. Run one after another, the
searches make thousands of calls of a few simulations each, and the per-call cost
dominates. Here each search is a generator that yields the point it needs next and
receives its value; :func:`drive` gathers one pending point of every search still going,
evaluates them all in one call, and hands the values back.

:func:`nelder_mead` is ``scipy.optimize.minimize(method="Nelder-Mead")`` (its initial
simplex, coefficients, ``adaptive`` variant, ``xatol``/``fatol`` test and ``maxfev``
budget) transcribed as such a generator, so that many of them share calls; it visits the
same points as SciPy's (``tests/test_search.py``). :func:`in_thread` makes any blocking
optimisation (SciPy's Powell or L-BFGS-B, say) such a search: it runs in its own thread,
which waits at each request until :func:`drive` has evaluated the round.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Generator, Sequence

import numpy as np

#: A search: yields what it needs evaluated (for Nelder-Mead a point), receives the value,
#: returns its result.
Search = Generator[object, object, object]


def drive(
    searches: Sequence[Search], evaluate: Callable[[list[np.ndarray], list[int]], np.ndarray]
) -> list[object]:
    """Run searches side by side; ``evaluate(points, which)`` values one point per search.

    Parameters
    ----------
    searches : sequence of generator
        The searches (started here).
    evaluate : callable
        ``evaluate(requests, which) -> values``: the pending requests of the searches
        ``which`` (their indices in ``searches``), in one call; each search receives its
        value as it is.

    Returns
    -------
    list
        Each search's return value.
    """
    results: list[object] = [None] * len(searches)
    pending: dict[int, np.ndarray] = {}
    try:
        for i, s in enumerate(searches):
            try:
                pending[i] = next(s)
            except StopIteration as stop:
                results[i] = stop.value
        while pending:
            order = sorted(pending)
            values = evaluate([pending[i] for i in order], order)
            nxt = {}
            for i, v in zip(order, values, strict=True):
                try:
                    nxt[i] = searches[i].send(v)
                except StopIteration as stop:
                    results[i] = stop.value
            pending = nxt
    except BaseException:
        for s in searches:  # every search stops (a threaded one ends its thread)
            s.close()
        raise
    return results


def in_thread(climb: Callable[[Callable[[object], object]], object]) -> Search:
    """A blocking optimisation as a search: ``climb(ask)`` runs in a thread of its own.

    Each ``ask(request)`` of the climb is yielded to :func:`drive` and returns the value
    the round gives it; the climb's return value is the search's. The thread only does the
    optimiser's bookkeeping between requests (the evaluation is :func:`drive`'s, on the
    calling thread), so a round holds one request of every climb, and each climb visits
    the points it visits alone, in the same order, on every run. An exception in the climb
    is raised from the search; a search closed early (another one failed) stops its thread.

    Parameters
    ----------
    climb : callable
        ``climb(ask) -> result``.

    Returns
    -------
    generator
        The search.
    """
    requests: queue.Queue = queue.Queue(maxsize=1)
    answers: queue.Queue = queue.Queue(maxsize=1)

    def ask(request: object) -> object:
        requests.put(("ask", request))
        kind, value = answers.get()
        if kind == "stop":
            raise _Stopped
        return value

    def run() -> None:
        try:
            requests.put(("done", climb(ask)))
        except _Stopped:
            requests.put(("stopped", None))
        except BaseException as exc:
            requests.put(("error", exc))

    def search() -> Search:
        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        answered = True
        try:
            while True:
                kind, payload = requests.get()
                if kind == "error":
                    raise payload
                if kind != "ask":
                    return payload
                answered = False
                value = yield payload
                answered = True
                answers.put(("value", value))
        finally:
            if not answered:  # closed at a request: the thread waits for its answer
                answers.put(("stop", None))
            thread.join()

    return search()


class _Stopped(Exception):
    """Raised in a climb's thread when its search is closed before the climb ended."""


def nelder_mead(
    x0: np.ndarray,
    *,
    maxfev: int,
    xatol: float = 1e-4,
    fatol: float = 1e-4,
    adaptive: bool = False,
) -> Search:
    """Nelder-Mead minimisation as a search generator (SciPy's algorithm).

    Parameters
    ----------
    x0 : ndarray
        Starting point.
    maxfev : int
        Most function evaluations.
    xatol, fatol : float
        Convergence tolerances on the simplex and its values.
    adaptive : bool
        Dimension-dependent coefficients (Gao & Han 2012), as SciPy's ``adaptive``.

    Yields
    ------
    ndarray
        The next point to evaluate.

    Returns
    -------
    tuple of (ndarray, float, int)
        The best point, its value and the evaluations made.
    """
    x0 = np.asarray(x0, dtype=float).ravel()
    n = len(x0)
    if adaptive:
        rho, chi, psi, sigma = 1.0, 1.0 + 2.0 / n, 0.75 - 1.0 / (2.0 * n), 1.0 - 1.0 / n
    else:
        rho, chi, psi, sigma = 1.0, 2.0, 0.5, 0.5
    sim = np.empty((n + 1, n))
    sim[0] = x0
    for k in range(n):
        y = x0.copy()
        y[k] = (1 + 0.05) * y[k] if y[k] != 0 else 0.00025
        sim[k + 1] = y
    fsim = np.full(n + 1, np.inf)
    calls = 0

    def order() -> None:
        nonlocal sim, fsim
        ind = np.argsort(fsim)
        sim, fsim = np.take(sim, ind, 0), np.take(fsim, ind, 0)

    for k in range(n + 1):
        if calls >= maxfev:
            break
        calls += 1
        fsim[k] = float((yield sim[k].copy()))
    order()
    while calls < maxfev:
        small = np.max(np.abs(sim[1:] - sim[0])) <= xatol
        if small and np.max(np.abs(fsim[0] - fsim[1:])) <= fatol:
            break
        xbar = np.add.reduce(sim[:-1], 0) / n
        xr = (1 + rho) * xbar - rho * sim[-1]
        calls += 1
        fxr = float((yield xr))
        shrink = False
        if fxr < fsim[0]:
            xe = (1 + rho * chi) * xbar - rho * chi * sim[-1]
            if calls >= maxfev:
                break
            calls += 1
            fxe = float((yield xe))
            if fxe < fxr:
                sim[-1], fsim[-1] = xe, fxe
            else:
                sim[-1], fsim[-1] = xr, fxr
        elif fxr < fsim[-2]:
            sim[-1], fsim[-1] = xr, fxr
        else:
            if fxr < fsim[-1]:
                xc = (1 + psi * rho) * xbar - psi * rho * sim[-1]
                if calls >= maxfev:
                    break
                calls += 1
                fxc = float((yield xc))
                if fxc <= fxr:
                    sim[-1], fsim[-1] = xc, fxc
                else:
                    shrink = True
            else:
                xcc = (1 - psi) * xbar + psi * sim[-1]
                if calls >= maxfev:
                    break
                calls += 1
                fxcc = float((yield xcc))
                if fxcc < fsim[-1]:
                    sim[-1], fsim[-1] = xcc, fxcc
                else:
                    shrink = True
            if shrink:
                for j in range(1, n + 1):
                    sim[j] = sim[0] + sigma * (sim[j] - sim[0])
                    if calls >= maxfev:
                        break
                    calls += 1
                    fsim[j] = float((yield sim[j].copy()))
        order()
    order()
    return sim[0].copy(), float(np.min(fsim)), calls
