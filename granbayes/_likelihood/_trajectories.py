"""Tracked jumps: positions of the foot and the rod at a camera's frames, and their noise.

A tracked jump is simulated once and its foot height ``x_f`` and rod displacement
``x_r(t) - x_r(0)`` read at every frame from the integrator's dense output
(physics-model.md section 5b). The observation model, per tracked jump:

* **Clock offset.** The camera's clock is off the command's by an unknown ``delta``:
  frame ``i`` shows the robot at ``t_i + delta``. Its prior is uniform over
  +/- ``K dt + h`` (``K = ceil(max_offset_frames)``, ``dt`` the jump's median frame
  interval, ``h`` half the grid step below). It is integrated out per jump, exactly for
  the model linearised in ``delta`` about the nearest point of a grid of step
  ``2 h = dt / s`` (``s`` sub-steps per frame interval, the fewest that make the step at
  most ``offset_step_ms``): the positions and velocities are simulated at
  ``t_i + m 2h`` for ``|m| <= K s`` (no extra simulations: more frames of the same one),
  and within ``|delta - m 2h| <= h`` the prediction is
  ``x(t_i + m 2h) + (delta - m 2h) v``. The log-likelihood is then quadratic in
  ``delta`` in each cell of the grid and its integral is a difference of normal CDFs. The
  linearisation errs by ``a h^2 / 2`` at most: at the default step of 0.25 ms, 2 um for
  an acceleration of 250 m/s^2 (a whole 2 ms frame interval as the step errs by up to
  0.12 mm on the reference robot, comparable with a camera's noise). Measured on a
  tracked jump at 500 frames/s against quadrature of the exact likelihood
  (``tests/test_kinds.py``): 0.52 nats off with a 2 ms step, 0.14 with 1 ms, 0.07 with
  0.5 ms, 0.006 with 0.25 ms (second order).
* **Autocorrelated frame noise.** Tracking errors drift over a few frames (a blurred
  marker, a lighting change): per coordinate, the residuals are an Ornstein-Uhlenbeck
  process of standard deviation ``frame_sd_<coordinate>_mm`` and correlation time
  ``frame_tau_ms`` (shared by both coordinates): exact for any frame spacing, the
  correlation of successive frames ``rho = exp(-dt / tau)``; its likelihood is that of the
  whitened residuals ``(r_i - rho_i r_{i-1}) / (sd sqrt(1 - rho_i^2))`` (the AR(1) exact
  likelihood; no library is needed for a first-order process: celerite2 would solve the
  same tridiagonal system more generally, at the cost of a dependency and of a per-jump
  Python loop over its solver).

The unit of leave-one-out is a whole tracked jump: its frames are not exchangeable.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping

import numba
import numpy as np
import pandas as pd
from scipy.special import log_ndtr
from scipy.stats import truncnorm

from .._priors import Prior
from ..commands import SETTINGS, CommandProgram, CommandSettings, build_command
from ._blocks import (
    Block,
    Coordinate,
    JumpRequest,
    Law,
    ObservationSettings,
    Simulated,
    coordinate_values,
    noise_coordinates,
)

__all__ = ["TrajectoryBlock"]

#: The position columns a tracked jump may have, and their index in a frame's output.
POSITIONS: tuple[str, ...] = ("x_foot_mm", "x_rod_mm")

#: Default priors of the frame noise: a tracking error from 10 um to 10 mm, and a
#: correlation time from white noise (10 us) to a drift over 100 ms.
FRAME_PRIORS: dict[str, Prior] = {
    "frame_sd_foot_mm": Prior(
        "loguniform", 0.01, 10.0, unit="mm", why="tracking error of the foot's height"
    ),
    "frame_sd_rod_mm": Prior(
        "loguniform", 0.01, 10.0, unit="mm", why="tracking error of the rod's displacement"
    ),
    "frame_tau_ms": Prior(
        "loguniform", 0.01, 100.0, unit="ms", why="correlation time of the tracking error"
    ),
}
_SD_OF = {"x_foot_mm": "frame_sd_foot_mm", "x_rod_mm": "frame_sd_rod_mm"}


def log_diff_ndtr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``log(Phi(b) - Phi(a))`` for ``a <= b``, accurate in both tails.

    Parameters
    ----------
    a, b : ndarray
        Lower and upper limits (broadcast).

    Returns
    -------
    ndarray
    """
    a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
    # in the upper tail use the mirror image: Phi(b) - Phi(a) = Phi(-a) - Phi(-b)
    flip = a > 0
    lo = np.where(flip, -b, a)
    hi = np.where(flip, -a, b)
    lhi, llo = log_ndtr(hi), log_ndtr(lo)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = lhi + np.log1p(-np.exp(llo - lhi))
    return np.where(hi > lo, out, -np.inf)


#: ``reassoc`` lets the compiler split the sums' chains of additions further, ``contract``
#: use fused multiply-adds: the sums change in the last bits only (about 1e-15 relative),
#: the same on every run, and the kernel runs about 1.4x faster than without.
_FAST = {"reassoc", "contract"}


@numba.njit(parallel=True, cache=True, fastmath=_FAST)
def _quadratic_sums(
    frames, cols, grid_index, y, gap_s, tau_s, sd, starts, sums, logdet
):  # pragma: no cover
    """Per walker, shift and jump, the sums of ``a a``, ``a b``, ``b b`` into ``sums``.

    ``frames`` (n, grid, 4): simulated positions [mm] and velocities [mm/s] at the grid
    points (``frames[..., col]`` and ``frames[..., 2 + col]``); ``cols`` (c,): the position
    columns measured; ``grid_index`` (shifts, frames): grid point of each frame at each
    shift; ``y`` (c, frames): the measurements, jump by jump; ``gap_s`` (frames,): each
    frame's spacing from the previous one of its jump (inf at a jump's first);
    ``tau_s`` (n, jumps) the correlation time [s] and ``sd`` (n, c, jumps) the noise
    [mm]; ``starts`` (jumps,): each jump's first frame. Writes ``sums`` (3, n, shifts,
    jumps), summed over the columns, and ``logdet`` (n, jumps): the sum of the log
    whitening scales ``log(sd sqrt(1 - rho^2))`` over frames and columns.

    The whitened residual and velocity of frame ``i`` are ``a = (r_i - rho_i r_{i-1}) /
    (sd sqrt(1 - rho_i^2))`` and ``b`` likewise, ``rho_i = exp(-gap_i / tau)``; the
    correlation terms, common to the columns and the shifts, are computed once per walker
    and jump, and ``1 / sd^2`` is applied to each column's sums once.
    """
    n = frames.shape[0]
    n_shift, n_frame = grid_index.shape
    n_jump = starts.shape[0]
    n_col = cols.shape[0]
    longest = 0
    for j in range(n_jump):
        hi = starts[j + 1] if j + 1 < n_jump else n_frame
        longest = max(longest, hi - starts[j])
    for w in numba.prange(n):
        rho = np.empty(longest)
        inv = np.empty(longest)  # 1 / sqrt(1 - rho^2)
        for j in range(n_jump):
            lo = starts[j]
            hi = starts[j + 1] if j + 1 < n_jump else n_frame
            log_s = 0.0
            for i in range(lo, hi):
                r = math.exp(-gap_s[i] / tau_s[w, j])
                s = math.sqrt(1.0 - r * r)
                rho[i - lo] = r
                inv[i - lo] = 1.0 / s
                log_s += math.log(s)
            det = 0.0
            for c in range(n_col):
                det += (hi - lo) * math.log(sd[w, c, j]) + log_s
            logdet[w, j] = det
            # two shifts side by side (the last one twice if their number is odd): their
            # sums are independent chains of additions, which the processor overlaps
            for k0 in range(0, n_shift, 2):
                k1 = min(k0 + 1, n_shift - 1)
                total0 = total1 = (0.0, 0.0, 0.0)
                for c in range(n_col):
                    col = cols[c]
                    run0 = run1 = (0.0, 0.0, 0.0, 0.0, 0.0)
                    for i in range(lo, hi):
                        q = rho[i - lo]
                        f = inv[i - lo]
                        g0 = grid_index[k0, i]
                        g1 = grid_index[k1, i]
                        run0 = _add_frame(
                            run0, y[c, i] - frames[w, g0, col], frames[w, g0, 2 + col], q, f
                        )
                        run1 = _add_frame(
                            run1, y[c, i] - frames[w, g1, col], frames[w, g1, 2 + col], q, f
                        )
                    isd2 = 1.0 / (sd[w, c, j] * sd[w, c, j])
                    total0 = _add_scaled(total0, run0, isd2)
                    total1 = _add_scaled(total1, run1, isd2)
                for m in range(3):
                    sums[m, w, k0, j] = total0[m]
                    sums[m, w, k1, j] = total1[m]


@numba.njit(inline="always", fastmath=_FAST)
def _add_frame(run, r, v, q, f):  # pragma: no cover
    """One frame into a shift's running sums ``(a a, a b, b b, r_prev, v_prev)``.

    ``r`` and ``v`` are the frame's residual [mm] and velocity [mm/s], ``q`` its
    correlation with the previous frame and ``f = 1 / sqrt(1 - q^2)``.
    """
    saa, sab, sbb, prev_r, prev_v = run
    a = (r - q * prev_r) * f
    b = (v - q * prev_v) * f
    return saa + a * a, sab + a * b, sbb + b * b, r, v


@numba.njit(inline="always", fastmath=_FAST)
def _add_scaled(total, run, scale):  # pragma: no cover
    """A column's sums ``run[:3]``, times ``scale = 1 / sd^2``, added to ``total``."""
    return total[0] + run[0] * scale, total[1] + run[1] * scale, total[2] + run[2] * scale


class TrajectoryBlock(Block):
    """Tracked jumps: frame positions with a clock offset and Ornstein-Uhlenbeck noise.

    Parameters
    ----------
    table : pandas.DataFrame
        Frames (``load_trajectories``): ``jump``, ``phi``, ``command``, ``t_s``,
        ``x_foot_mm`` and/or ``x_rod_mm``, and the command settings.
    settings : ObservationSettings, optional
        ``max_offset_frames`` (and ``sigma_mode``: the noise per volume fraction, or
        once).
    """

    kind = "trajectories"
    unit_dim = "trajectory"
    variable = "tracked_jump"  # not the dimension's name: xarray would take it for it

    def __init__(self, table: pd.DataFrame, settings: ObservationSettings | None = None) -> None:
        settings = settings or ObservationSettings()
        self.settings = settings
        self._table = table.reset_index(drop=True)
        t = self._table
        self.positions = tuple(c for c in POSITIONS if c in t.columns)
        codes, _ = pd.factorize(t["jump"].astype(str), sort=False)
        self._unit = np.asarray(codes, dtype=np.int64)
        n = int(self._unit.max()) + 1 if len(self._unit) else 0
        self._n_units = n
        self._phis = np.unique(t["phi"].to_numpy(float))
        order = np.argsort(self._unit, kind="stable")
        self._order = order  # frames grouped by jump, time order within (validated)
        self._starts = np.searchsorted(self._unit[order], np.arange(n)).astype(np.int64)
        first = order[self._starts]
        self._unit_phi = t["phi"].to_numpy(float)[first]
        programs: list[CommandProgram] = []
        for i in first:
            row = t.iloc[int(i)]
            cs = CommandSettings(**{s: float(row[s]) for s in SETTINGS})
            programs.append(build_command(str(row["command"]), cs))
        self._programs = programs
        # the frame grid of every jump: its frames' times shifted by whole sub-steps
        self.k_max = math.ceil(settings.max_offset_frames)
        bounds = np.append(self._starts, len(order))
        times = t["t_s"].to_numpy(float)[order]
        dts = np.array(
            [
                float(np.median(np.diff(times[a:b]))) if b - a > 1 else 1e-3
                for a, b in itertools.pairwise(bounds)
            ]
        )
        # sub-steps per frame interval: the offset grid is at most offset_step_ms apart
        max_dt = float(dts.max()) if n else 1e-3
        self.substeps = max(1, math.ceil(max_dt / (1e-3 * settings.offset_step_ms) - 1e-9))
        shifts = np.arange(-self.k_max * self.substeps, self.k_max * self.substeps + 1)
        grids, index = [], []
        offset = 0
        for j in range(n):
            tj = times[bounds[j] : bounds[j + 1]]
            step = dts[j] / self.substeps
            wanted = tj[None, :] + shifts[:, None] * step  # (shifts, frames)
            key = np.round(wanted / (step * 1e-6)).astype(np.int64)
            uniq, inverse = np.unique(key, return_inverse=True)
            grid = np.empty(len(uniq))
            grid[inverse.reshape(-1)] = wanted.reshape(-1)
            grids.append(grid)
            index.append(inverse.reshape(wanted.shape) + offset)
            offset += len(grid)
        self._grids = grids
        self._grid_index = (
            np.concatenate(index, axis=1) if index else np.empty((len(shifts), 0), int)
        ).astype(np.int64)
        self._dt = dts
        self._step = dts / self.substeps  # spacing of the offset grid per jump [s]
        self._frame_dt = dts[self._unit[order]]
        self._y = {c: t[c].to_numpy(float)[order] for c in self.positions}
        # the measured columns as the compiled sums take them
        self._columns = np.array([POSITIONS.index(c) for c in self.positions], dtype=np.int64)
        self._y_columns = np.stack([self._y[c] for c in self.positions])
        # spacing of each frame from the previous one of its jump (inf: the first)
        gap = np.diff(times, prepend=np.nan)
        gap[self._starts] = np.inf
        self._gap_s = gap
        self._coords: list[Coordinate] = []

    # ------------------------------------------------------------------------------------
    @property
    def table(self) -> pd.DataFrame:
        """The frames."""
        return self._table

    @property
    def n_units(self) -> int:
        """Number of tracked jumps."""
        return self._n_units

    @property
    def phis(self) -> np.ndarray:
        """Volume fractions of the tracked jumps."""
        return self._phis

    def coordinates(self, priors: Mapping[str, Prior], phis: np.ndarray) -> list[Coordinate]:
        """The frame noise of each position column and its correlation time.

        Per volume fraction of the tracked jumps (one each, ``sigma_mode="global"``).

        Parameters
        ----------
        priors : mapping of str to Prior
            Overrides of :data:`FRAME_PRIORS` by name.
        phis : ndarray
            Volume fractions of the whole model (unused).

        Returns
        -------
        list of Coordinate
        """
        names = [_SD_OF[c] for c in self.positions] + ["frame_tau_ms"]
        per_phi = self.settings.sigma_mode != "global"
        coords = [
            c
            for name in names
            for c in noise_coordinates(
                name, priors.get(name, FRAME_PRIORS[name]), self._phis, per_phi
            )
        ]
        self._coords = coords
        return list(coords)

    def with_data(self, table: pd.DataFrame) -> TrajectoryBlock:
        """Other tracked jumps under this block's coordinates.

        Parameters
        ----------
        table : pandas.DataFrame
            Frames at volume fractions this block has noise parameters for.

        Returns
        -------
        TrajectoryBlock
        """
        other = TrajectoryBlock(table, self.settings)
        other._coords = self._coords
        return other

    def offset_windows_s(self) -> dict:
        """Half-width [s] of each tracked jump's clock-offset prior, by its ``jump`` value.

        The offset is uniform on ``+/- (K dt + h)`` (module docstring): what a simulation
        of this model's prior predictive must draw.

        Returns
        -------
        dict
            ``jump`` value -> half-width [s].
        """
        ids = self._table["jump"].to_numpy()[self._order[self._starts]]
        half = self.k_max * self._dt + 0.5 * self._step
        return {ids[j]: float(half[j]) for j in range(self._n_units)}

    def jump_request(self) -> JumpRequest:
        """One simulation per tracked jump, read at its frame grid."""
        return JumpRequest(self._unit_phi, self._programs, self._grids)

    def values(self, u: np.ndarray, phis: np.ndarray) -> dict[str, np.ndarray]:
        """The noise parameters at ``phis`` (NaN where not fitted).

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates.
        phis : ndarray
            Volume fractions.

        Returns
        -------
        dict of str to ndarray, shape (n, len(phis))
        """
        return coordinate_values(self._coords, u, phis)

    def _per_jump(self, u: np.ndarray, name: str) -> np.ndarray:
        """A noise parameter of every tracked jump: (n, n_jumps)."""
        at = self.values(u, self._phis)[name]
        if np.any(np.isnan(at)):
            raise ValueError(f"no fitted {name} at some phi of these tracked jumps")
        return at[:, np.searchsorted(self._phis, self._unit_phi)]

    def _per_frame(self, u: np.ndarray, name: str) -> np.ndarray:
        """A noise parameter at every frame (jump order): (n, n_frames)."""
        return self._per_jump(u, name)[:, self._unit[self._order]]

    # ------------------------------------------------------------------------------------
    def _shift_terms(self, u: np.ndarray, sim: Simulated):
        """Per walker, shift and jump: the quadratic form in ``eps = delta - k step``.

        ``ll(eps) = C - (A - 2 eps B + eps^2 D) / 2`` with ``A``, ``B``, ``D`` the sums
        over a jump's frames (and both coordinates) of the whitened residuals ``a`` and
        velocities ``b``: ``a a``, ``a b``, ``b b`` (:func:`_quadratic_sums`, compiled: the
        (walker, shift, frame) arrays are never stored). Returns ``C`` of shape
        (n, 1, jumps) and ``A, B, D`` of shape (n, shifts, jumps).
        """
        n, n_shift, n_jump = u.shape[0], self._grid_index.shape[0], self._n_units
        tau_s = 1e-3 * self._per_jump(u, "frame_tau_ms")
        sd = np.stack([self._per_jump(u, _SD_OF[c]) for c in self.positions], axis=1)
        sums = np.empty((3, n, n_shift, n_jump))
        logdet = np.empty((n, n_jump))
        _quadratic_sums(
            np.ascontiguousarray(sim.frames, dtype=float),
            self._columns,
            self._grid_index,
            self._y_columns,
            self._gap_s,
            np.ascontiguousarray(tau_s),
            np.ascontiguousarray(sd),
            self._starts,
            sums,
            logdet,
        )
        frames_per_jump = np.diff(np.append(self._starts, len(self._order)))
        per_frame = 0.5 * math.log(2.0 * math.pi) * len(self.positions)
        C = (-logdet - per_frame * frames_per_jump)[:, None, :]
        return C, sums[0], sums[1], sums[2]

    def _log_integrals(self, C, A, B, D):
        """Per walker, shift and jump: log of the likelihood integrated over its interval.

        Also returns the mean and precision of ``eps`` within each interval.
        """
        h = 0.5 * self._step[None, None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            mu = B / D
            sq = np.sqrt(D)
            moving = D * h * h > 1e-12
            # the integral over eps in [-h, h] of exp(-(A - 2 eps B + eps^2 D) / 2)
            gauss = (
                -0.5 * (A - B * mu)
                + 0.5 * math.log(2.0 * math.pi)
                - np.log(sq)
                + log_diff_ndtr((-h - mu) * sq, (h - mu) * sq)
            )
            still = -0.5 * A + np.log(2.0 * h)
        return np.where(moving, gauss, still) + C, np.where(moving, mu, 0.0), D, moving

    def log_lik(self, u: np.ndarray, law: Law, sim: Simulated | None) -> np.ndarray:
        """Log-likelihood of every tracked jump, its clock offset integrated out.

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates.
        law : Law
            The force law (unused: the simulation carries it).
        sim : Simulated
            Positions and velocities at every frame of the grid.

        Returns
        -------
        ndarray, shape (n, n_jumps)
            ``-inf`` where a simulation failed.
        """
        ok = np.all(sim.ok, axis=1)
        log_int, *_ = self._log_integrals(*self._shift_terms(u, sim))
        n_shift = log_int.shape[1]
        with np.errstate(invalid="ignore"):
            ll = np.logaddexp.reduce(log_int, axis=1) - np.log(n_shift * self._step)[None, :]
        ll[~np.isfinite(ll)] = -np.inf
        ll[~ok] = -np.inf
        return ll

    #: Most draws whose replicated trajectories a fit keeps (thinned evenly): frames are
    #: many, and bands and residual cells need a few hundred draws, not thousands.
    max_predictive_draws: int | None = 200

    @property
    def predictive_dims(self) -> dict[str, str]:  # type: ignore[override]
        """Replicated and simulated positions, over the frames."""
        out = {}
        for c in self.positions:
            out[c] = "frame"
            out[c.replace("_mm", "_sim_mm")] = "frame"
        return out

    def predictive(
        self, u: np.ndarray, law: Law, sim: Simulated | None, rng: np.random.Generator
    ) -> dict[str, np.ndarray]:
        """Replicated positions [mm] of every frame, and the simulated ones.

        Each draw's clock offset of each jump is drawn from its conditional posterior given
        the measured frames (the shift by the weights of :meth:`log_lik`'s terms, then the
        offset within it from its truncated normal), the positions are the simulated ones
        at the offset time (linearised as in the likelihood), and the replicates add one
        draw of the Ornstein-Uhlenbeck frame noise.

        Parameters
        ----------
        u : ndarray, shape (n, n_coordinates)
            The block's coordinates of n draws.
        law : Law
            The force law (unused).
        sim : Simulated
            Positions and velocities at the frame grid.
        rng : numpy.random.Generator
            Source of the offsets and the noise.

        Returns
        -------
        dict of str to ndarray, shape (n, n_frames)
            ``x_foot_mm``/``x_rod_mm`` (replicated) and ``x_foot_sim_mm``/``x_rod_sim_mm``
            (no noise), for the position columns the data have, in table row order.
        """
        n = u.shape[0]
        log_int, mu, D, moving = self._log_integrals(*self._shift_terms(u, sim))
        # the shift of each (draw, jump), then the offset within its interval
        w = np.exp(log_int - np.max(log_int, axis=1, keepdims=True))
        w = np.nan_to_num(w / np.sum(w, axis=1, keepdims=True), nan=1.0 / w.shape[1])
        cum = np.cumsum(w, axis=1)
        pick = np.minimum((rng.random((n, 1, w.shape[2])) > cum).sum(axis=1), w.shape[1] - 1)
        take = pick[:, None, :]
        h = 0.5 * self._step[None, :]
        mu_k = np.take_along_axis(mu, take, 1)[:, 0]
        d_k = np.take_along_axis(D, take, 1)[:, 0]
        mov = np.take_along_axis(moving, take, 1)[:, 0]
        sd = 1.0 / np.sqrt(np.where(mov, d_k, 1.0))
        lo, hi = (-h - mu_k) / sd, (h - mu_k) / sd
        eps_normal = mu_k + sd * truncnorm.rvs(
            np.where(mov, lo, -1.0), np.where(mov, hi, 1.0), random_state=rng
        )
        eps = np.where(mov, eps_normal, rng.uniform(-h, h, size=mu_k.shape))
        frame_jump = self._unit[self._order]
        shift = pick[:, frame_jump]  # (n, frames)
        index = self._grid_index[shift, np.arange(len(frame_jump))[None, :]]
        eps_f = eps[:, frame_jump]
        tau_s = 1e-3 * self._per_frame(u, "frame_tau_ms")
        with np.errstate(over="ignore"):
            rho = np.exp(-self._gap_s[None, :] / tau_s)
        s = np.sqrt(1.0 - rho * rho)
        back = np.empty_like(self._order)
        back[self._order] = np.arange(len(self._order))
        out = {}
        for c in self.positions:
            col = POSITIONS.index(c)
            x = sim.frames[np.arange(n)[:, None], index, col]
            v = sim.frames[np.arange(n)[:, None], index, 2 + col]
            mean = x + eps_f * v
            sdf = self._per_frame(u, _SD_OF[c])
            z = rng.standard_normal(mean.shape)
            e = np.empty_like(mean)
            e[:, 0] = sdf[:, 0] * z[:, 0]
            for i in range(1, mean.shape[1]):  # the Ornstein-Uhlenbeck recursion
                e[:, i] = rho[:, i] * e[:, i - 1] + sdf[:, i] * s[:, i] * z[:, i]
            out[c] = (mean + e)[:, back]
            out[c.replace("_mm", "_sim_mm")] = mean[:, back]
        return out
