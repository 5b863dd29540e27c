"""The track surface under a line as the QSS model and the follower read it: slope, banking,
vertical curvature, friction and rolling resistance per sample, and the forces they imply.

The simulator's car (``sim.kernels.surface_normal_load``, docs/sim.md "Heights and banking")
feels gravity along the slope, a normal load ``m (g cos(grade) cos(bank) - v^2 kv - a_lat
sin(bank)) + downforce`` and, across the track, gravity's in-plane part ``-g cos(grade)
sin(bank)``, with its tyres making the rest of the path's lateral acceleration over
``cos(bank)``. A speed plan that ignored these planned the car off the low side of every
banked straight (b-speedway, 15 deg: the steering law's steady error was ~1.6 m) and into crests
too fast; this module is the one place that writes those forces for the planners, so the QSS
passes and the follower cannot disagree about them.

Values are the track's at each centreline sample (the simulator reads the sample under the car,
whatever its lateral offset), so a line's sample ``i`` uses the track's sample ``i``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np

from formula_tourney.sim.car_params import GRAVITY_MPS2
from formula_tourney.sim.track import Track

# Columns of :meth:`PathSurface.packed` (what the compiled passes read per sample).
S_SIN_GRADE, S_G_NORMAL, S_G_LATERAL, S_KV, S_SIN_BANK, S_COS_BANK, S_GRIP, S_ROLLING = range(8)
N_SURFACE = 8


@dataclass(frozen=True, eq=False)
class PathSurface:
    """Per-sample surface of a closed line (one value per track sample).

    ``grip`` multiplies the car's ``mu`` (the road surface's friction, a section's grip factor,
    the episode's ``grip_scale``); ``rolling`` adds to its rolling-resistance coefficient.
    """

    slope_rad: np.ndarray
    banking_rad: np.ndarray
    vertical_curvature_1pm: np.ndarray
    grip: np.ndarray
    rolling: np.ndarray

    @classmethod
    def of_track(cls, track: Track, grip_scale: float = 1.0) -> PathSurface | None:
        """The surface of ``track`` at ``grip_scale``; None when it is level asphalt at grip 1
        (the planners then run their flat arithmetic unchanged: flat lap times are pinned)."""
        grip = np.asarray(track.friction_road, dtype=float) * float(grip_scale)
        rolling = np.asarray(track.rolling_road, dtype=float)
        if not track.has_surface and np.all(grip == 1.0) and not np.any(rolling):
            return None
        return cls(track.slope_rad, track.banking_rad, track.vertical_curvature_1pm, grip,
                   rolling)

    def with_compression_share(self, share: float) -> PathSurface:
        """The same surface with compressions (vertical curvature < 0) counted at ``share`` of
        their extra load; crests unchanged. A planner that must not arrive too fast (the
        follower) plans with less than the load a compression really gives for a few metres."""
        kv = self.vertical_curvature_1pm
        return replace(self, vertical_curvature_1pm=np.where(kv < 0.0, share * kv, kv))

    @property
    def n(self) -> int:
        return int(self.slope_rad.shape[0])

    def packed(self) -> np.ndarray:
        """``(n, N_SURFACE)`` rows: sin(grade), g cos(grade) cos(bank), g cos(grade) sin(bank),
        vertical curvature, sin(bank), cos(bank), grip, extra rolling resistance."""
        th, b = self.slope_rad, self.banking_rad
        out = np.empty((self.n, N_SURFACE))
        out[:, S_SIN_GRADE] = np.sin(th)
        out[:, S_G_NORMAL] = GRAVITY_MPS2 * np.cos(th) * np.cos(b)
        out[:, S_G_LATERAL] = GRAVITY_MPS2 * np.cos(th) * np.sin(b)
        out[:, S_KV] = self.vertical_curvature_1pm
        out[:, S_SIN_BANK] = np.sin(b)
        out[:, S_COS_BANK] = np.cos(b)
        out[:, S_GRIP] = self.grip
        out[:, S_ROLLING] = self.rolling
        return np.ascontiguousarray(out)


@numba.njit(cache=True)
def surface_forces(row: np.ndarray, mass_kg: float, downforce_coef: float, u: float,
                   curvature_1pm: float) -> tuple[float, float, float]:
    """``(normal load, tyre lateral force, gravity along the path)`` in N at speed^2 ``u`` on a
    path of horizontal curvature ``curvature_1pm`` (left > 0) over surface ``row``.

    The tyre lateral force is what the path needs less what gravity gives across the banked
    plane, ``m (u k cos(bank) + g cos(grade) sin(bank))`` (signed, left > 0); the gravity term
    is > 0 uphill (it resists). The normal load is never below 0 (the car leaves a sharp crest).
    """
    normal = (mass_kg * (row[S_G_NORMAL] - u * row[S_KV] - u * curvature_1pm * row[S_SIN_BANK])
              + downforce_coef * u)
    lateral = mass_kg * (u * curvature_1pm * row[S_COS_BANK] + row[S_G_LATERAL])
    along = mass_kg * GRAVITY_MPS2 * row[S_SIN_GRADE]
    return max(normal, 0.0), lateral, along


def corner_speed_on_surface_mps(curvature_1pm: np.ndarray, surface: np.ndarray, mass_kg: float,
                                mu: float, downforce_coef: float, drag_coef: float,
                                rolling_resistance: float, cap_mps: float) -> np.ndarray:
    """Steady-state speed limit per sample on a sloped, banked, curved surface, in closed form.

    With ``u = v^2`` the normal load ``N = n0 + n1 u``, the tyre lateral force ``y0 + y1 u`` and
    the longitudinal force that holds the speed ``x0 + x1 u`` (drag, rolling resistance on
    ``N``, gravity along the slope) are affine in ``u`` (:func:`surface_forces`); the friction
    circle ``y^2 + x^2 <= (mu grip N)^2`` is then a quadratic in ``u`` whose larger root is the
    limit, and ``N >= 0`` caps it on a crest. On a level, unbanked sample it is the flat
    closed form of ``speed_profile.corner_speed_mps``; on a banked turn it gives the textbook
    ``v^2 = R g (sin b + mu cos b) / (cos b - mu sin b)`` (no aero, no drag; tests).
    """
    k = np.asarray(curvature_1pm, dtype=float)
    s = surface
    m = mass_kg
    mu_i = mu * s[:, S_GRIP]
    crr = rolling_resistance + s[:, S_ROLLING]
    n0 = m * s[:, S_G_NORMAL]
    n1 = downforce_coef - m * s[:, S_KV] - m * k * s[:, S_SIN_BANK]
    y0 = m * s[:, S_G_LATERAL]
    y1 = m * k * s[:, S_COS_BANK]
    x0 = crr * n0 + m * GRAVITY_MPS2 * s[:, S_SIN_GRADE]
    x1 = drag_coef + crr * n1
    a2 = y1 * y1 + x1 * x1 - (mu_i * n1) ** 2
    a1 = 2.0 * (y0 * y1 + x0 * x1 - mu_i * mu_i * n0 * n1)
    a0 = y0 * y0 + x0 * x0 - (mu_i * n0) ** 2
    cap = cap_mps * cap_mps
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = a1 * a1 - 4.0 * a2 * a0
        root = (-a1 + np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a2)
        lift_off = np.where(n1 < 0.0, n0 / -n1, np.inf)
    # a2 <= 0: the grip grows at least as fast as the demand, no limit from this sample.
    u = np.where(a2 > 1e-12, np.where(disc >= 0.0, np.clip(root, 0.0, cap), 0.0), cap)
    u = np.minimum(u, lift_off)
    return np.sqrt(np.maximum(u, MIN_CORNER_SPEED_MPS**2))


MIN_CORNER_SPEED_MPS = 1.0
"""Floor of a corner speed: a sample the car cannot hold at any speed (a bank steeper than its
friction angle) still gets a finite lap time, and the follower crawls there."""


def normal_load_n(row: np.ndarray, mass_kg: float, downforce_coef: float, speed_mps: float,
                  curvature_1pm: float) -> float:
    """:func:`surface_forces`' normal load, for Python callers (the follower)."""
    return surface_forces(row, mass_kg, downforce_coef, speed_mps * speed_mps,
                          curvature_1pm)[0]

