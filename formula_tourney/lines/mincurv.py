"""Minimum-curvature racing line: an iterated QP over lateral offsets (quadprog).

Minimise the summed squared curvature of the line ``p_i = c_i + a_i n_i`` (centre ``c``, unit
left normal ``n``, offset ``a``) subject to ``-w_right + margin <= a <= w_left - margin``.
Curvature is non-linear in ``a``; like TUM's ``opt_min_curv`` + ``iqp_handler`` we linearise it
around the current solution, solve the QP, and iterate around the new solution until the
linearisation error (the change of the line) is small. We linearise the *whole* curvature
(first and second derivatives, a Gauss-Newton step with a small damping term) instead of
freezing the first derivatives, which converges in a handful of iterations.

Measured trade-offs (docs/lines.md): a dense QP of ~900 points solves in ~0.4 s with
quadprog on one thread (OSQP took ~7 s on 500 points; scipy's lsq_linear was off by metres), so
the QP runs on every k-th track sample (spacing >= 3 m, at most ``MAX_QP_POINTS`` points). The
fine line is then a periodic C2 spline *through the optimal points* intersected with every
track normal; splining the offsets instead would carry the centreline's curvature jumps at
straight/arc joins into the line, and clipping offsets would add kinks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import quadprog
from scipy.interpolate import CubicSpline

from formula_tourney.errors import UserInputError
from formula_tourney.sim.track import Track

DEFAULT_MARGIN_M = 2.0
"""Kept free on each side: half the car (0.95 m) plus room for the follower's tracking error
(with 1.5 m it left the asphalt once in 26 test drives, running 1.6 m wide out of a hairpin)."""

MAX_QP_POINTS = 600
"""quadprog is O(n^3): 600 points ~0.15 s per iteration here, 1200 points ~1.3 s (and up to
18 s for a whole solve). On a 2.2 km technical track 279, 446 and 743 points gave QSS laps
within 0.1% of each other, so resolution beyond ~8 m buys nothing."""

MIN_QP_SPACING_M = 3.0


@dataclass
class MinCurvResult:
    """Offsets per track sample plus what the solver did (for tests and the CLI)."""

    offsets_m: np.ndarray
    qp_offsets_m: np.ndarray
    qp_indices: np.ndarray
    lower_m: np.ndarray
    upper_m: np.ndarray
    iterations: int
    seconds: float
    objective_history: list[float] = field(default_factory=list)


def _second_diff(n: int) -> np.ndarray:
    d2 = -2.0 * np.eye(n)
    d2 += np.roll(np.eye(n), 1, axis=1) + np.roll(np.eye(n), -1, axis=1)
    return d2


def _first_diff(n: int) -> np.ndarray:
    return 0.5 * (np.roll(np.eye(n), 1, axis=1) - np.roll(np.eye(n), -1, axis=1))


def _curvature_and_jacobian(cx, cy, nx, ny, a, d1, d2):
    """Curvature of the closed polyline (uniform parameter) and its Jacobian in ``a``."""
    x, y = cx + nx * a, cy + ny * a
    xp, yp = d1 @ x, d1 @ y
    xpp, ypp = d2 @ x, d2 @ y
    s2 = xp * xp + yp * yp
    s3 = s2 ** 1.5
    kappa = (xp * ypp - yp * xpp) / s3
    d1nx, d1ny = d1 * nx[None, :], d1 * ny[None, :]
    d2nx, d2ny = d2 * nx[None, :], d2 * ny[None, :]
    jac = (
        (ypp / s3)[:, None] * d1nx + (xp / s3)[:, None] * d2ny
        - (xpp / s3)[:, None] * d1ny - (yp / s3)[:, None] * d2nx
        - (3.0 * kappa * xp / s2)[:, None] * d1nx - (3.0 * kappa * yp / s2)[:, None] * d1ny
    )
    return kappa, jac


def offset_bounds(track: Track, margin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Allowed offsets per sample; where the track is narrower than two margins, its middle."""
    lower = -track.width_right_m + margin_m
    upper = track.width_left_m - margin_m
    narrow = lower > upper
    mid = 0.5 * (track.width_left_m - track.width_right_m)
    lower = np.where(narrow, mid, lower)
    upper = np.where(narrow, mid, upper)
    return lower, upper


def mincurv(
    track: Track,
    margin_m: float = DEFAULT_MARGIN_M,
    max_iterations: int = 12,
    tolerance_m: float = 0.005,
    max_points: int = MAX_QP_POINTS,
) -> MinCurvResult:
    """Solve the iterated min-curvature QP on ``track`` and return the fine line's offsets."""
    if margin_m < 0:
        raise UserInputError(f"margin must be >= 0 m, got {margin_m}")
    if max_iterations < 1:
        raise UserInputError(f"max_iterations must be >= 1, got {max_iterations}")
    t0 = time.perf_counter()
    spacing = track.length_m / track.n
    step = max(int(np.ceil(MIN_QP_SPACING_M / spacing)),
               int(np.ceil(track.n / max(max_points, 16))), 1)
    idx = np.arange(0, track.n, step)
    if idx.size < 16:
        raise UserInputError(f"track {track.name!r} is too short for a min-curvature line")
    n = idx.size
    cx, cy = track.x_m[idx], track.y_m[idx]
    nx, ny = -np.sin(track.heading_rad[idx]), np.cos(track.heading_rad[idx])
    lower_all, upper_all = offset_bounds(track, margin_m)
    lower, upper = lower_all[idx], upper_all[idx]
    d1, d2 = _first_diff(n), _second_diff(n)
    a = np.clip(np.zeros(n), lower, upper)
    constraint = np.hstack([np.eye(n), -np.eye(n)])
    history: list[float] = []
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (reported after the loop)
        kappa, jac = _curvature_and_jacobian(cx, cy, nx, ny, a, d1, d2)
        history.append(float(kappa @ kappa))
        hessian = jac.T @ jac
        # Damping keeps the Hessian positive definite (quadprog needs it) and the step inside
        # the region where the linearisation holds.
        damping = 1e-9 * float(np.trace(hessian)) / n + 1e-12
        hessian[np.diag_indices(n)] += damping
        gradient = -(jac.T @ kappa)
        bounds = np.concatenate([lower - a, -(upper - a)])
        # Tiny slack: equal bounds (narrow places) must stay feasible in floating point.
        step_m = quadprog.solve_qp(hessian, gradient, constraint, bounds - 1e-9, 0)[0]
        a = np.clip(a + step_m, lower, upper)
        if float(np.max(np.abs(step_m))) < tolerance_m:
            break
    kappa, _ = _curvature_and_jacobian(cx, cy, nx, ny, a, d1, d2)
    history.append(float(kappa @ kappa))
    fine = spline_offsets(track, track.s_m[idx], cx + nx * a, cy + ny * a, a)
    fine = np.clip(fine, -track.width_right_m + 0.5 * margin_m,
                   track.width_left_m - 0.5 * margin_m)
    return MinCurvResult(
        offsets_m=fine, qp_offsets_m=a, qp_indices=idx, lower_m=lower, upper_m=upper,
        iterations=iterations, seconds=time.perf_counter() - t0, objective_history=history,
    )


def mincurv_offsets(track: Track, margin_m: float = DEFAULT_MARGIN_M) -> np.ndarray:
    """Offsets of the minimum-curvature line, one per track sample."""
    return mincurv(track, margin_m).offsets_m


def spline_offsets(track: Track, s_nodes_m: np.ndarray, px: np.ndarray, py: np.ndarray,
                   guess_m: np.ndarray, smoothing_m: float = 0.0) -> np.ndarray:
    """Offsets at every track sample of a periodic C2 spline through points ``(px, py)``.

    ``s_nodes_m`` (increasing, in ``[0, length)``) is the track position of each point and
    ``guess_m`` its offset. The spline is parameterised by chord length; each track normal is
    intersected with it by Newton's method on the spline parameter. With ``smoothing_m > 0``
    the spline may pass up to about that distance (RMS) from the points (a periodic smoothing
    spline, FITPACK's ``s = m * sigma^2``): measured laps carry noise an interpolant would turn
    into curvature. Shared by the recorded and genetic lines.
    """
    px = np.asarray(px, dtype=float)
    py = np.asarray(py, dtype=float)
    chord = np.hypot(np.diff(np.append(px, px[0])), np.diff(np.append(py, py[0])))
    t_nodes = np.concatenate([[0.0], np.cumsum(chord)])
    period = float(t_nodes[-1])
    if smoothing_m > 0.0:
        from scipy.interpolate import splev, splprep

        tck, _ = splprep([np.append(px, px[0]), np.append(py, py[0])], u=t_nodes,
                         s=px.size * smoothing_m**2, per=1, k=3)

        def curve(t: np.ndarray, der: int = 0) -> tuple[np.ndarray, np.ndarray]:
            out = splev(t, tck, der=der)
            return np.asarray(out[0]), np.asarray(out[1])
    else:
        sx = CubicSpline(t_nodes, np.append(px, px[0]), bc_type="periodic")
        sy = CubicSpline(t_nodes, np.append(py, py[0]), bc_type="periodic")

        def curve(t: np.ndarray, der: int = 0) -> tuple[np.ndarray, np.ndarray]:
            return sx(t, der), sy(t, der)

    s_nodes = np.asarray(s_nodes_m, dtype=float)
    length = track.length_m
    guess = np.interp(track.s_m, s_nodes, guess_m, period=length)
    # Initial parameter: interpolate the node parameters in track arc length, periodically
    # (the parameter grows by ``period`` per lap, so interpolate its periodic remainder).
    ratio = period / length
    t = np.interp(track.s_m, s_nodes, t_nodes[:-1] - ratio * s_nodes, period=length)
    t = t + ratio * track.s_m
    hx, hy = np.cos(track.heading_rad), np.sin(track.heading_rad)
    for _ in range(8):
        tm = np.mod(t, period)
        cx, cy = curve(tm)
        g = (cx - track.x_m) * hx + (cy - track.y_m) * hy
        dx, dy = curve(tm, 1)
        dg = dx * hx + dy * hy
        t = t - g / np.where(np.abs(dg) > 1e-6, dg, 1e-6)
    cx, cy = curve(np.mod(t, period))
    offsets = (cx - track.x_m) * (-hy) + (cy - track.y_m) * hx
    bad = ~np.isfinite(offsets)
    offsets[bad] = guess[bad]
    return offsets
