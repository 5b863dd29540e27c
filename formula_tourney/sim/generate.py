"""Procedural tracks: a seed becomes a closed, non-overlapping track of straights and arcs.

Construction (exactly closed by geometry, no numerical solve needed):

1. A star-shaped polygon: 7-13 vertices at sorted random angles around a centre, each at a
   random distance, then stretched along a random axis. Vertices sorted by angle around a
   point they all see make a simple (non-self-intersecting) polygon, and a linear stretch keeps
   it simple. Dents (vertices pulled towards the centre) give right-hand corners in an
   anticlockwise lap, so tracks mix left and right turns.
2. Every corner is rounded by a tangent arc (a fillet) of a random radius >= ``min_radius_m``;
   the arc eats ``R * tan(|theta| / 2)`` of each adjacent edge, the rest of each edge stays a
   straight. A polygon's exterior angles sum to exactly +-360 deg and fillets keep the ends of
   every edge on the polygon, so the segment list closes to float rounding (~1e-9 m).
3. The polygon is scaled so that the lap has a random target length within the bounds.
4. The start line goes 40% of the way along the longest straight (the env starts cars 50 m
   before it), so segment 0 is the rest of that straight.
5. The spec goes through :func:`~formula_tourney.sim.segments.build_track`, whose closure and
   asphalt-overlap checks decide; a refused or out-of-bounds attempt is retried with the
   derived seed ``(seed, attempt)``, so the same seed always yields the same track.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.sim.segments import SegmentSpec, TrackSpec, build_track
from formula_tourney.sim.track import Track

DEFAULT_MIN_LENGTH_M = 1500.0
DEFAULT_MAX_LENGTH_M = 4000.0
DEFAULT_MIN_WIDTH_M = 8.0
DEFAULT_MAX_WIDTH_M = 14.0
DEFAULT_MIN_RADIUS_M = 12.0
MAX_CORNER_RADIUS_M = 300.0
"""Fillet radii are drawn log-uniformly up to this: hairpins to fast sweepers."""

MIN_STRAIGHT_M = 10.0
"""Every polygon edge keeps at least this much straight between two corners."""

MAX_CORNER_DEG = 150.0
"""Sharper polygon corners are rejected: their fillets would eat whole edges."""

MAX_ATTEMPTS = 200
MAX_SEED = 999_999_999
"""Largest seed; ``catalog.check_track_name`` refuses ``gen-<seed>`` names beyond it."""

GENERATED_KINDS: dict[str, dict[str, float]] = {
    "gen": {},
    "gen-short": {"min_length_m": 800.0, "max_length_m": 1600.0},
}
"""Each kind of generated track by its name prefix (``<prefix>-<seed>``), with the bounds it
sets beside the defaults. ``gen-short`` laps are 0.8-1.6 km with as many corners as ``gen``'s
1.5-4 km, so tight corners take a larger share of the lap: a median ~8 % of it under 40 m of
radius against ``gen``'s ~3 %, as on the slow tracks (technical 8 %, aalborg 16 %), which a
driver trained on ``gen`` tracks alone sees too seldom."""

GENERATED_FORMS = " or ".join(f"{prefix}-<seed>" for prefix in GENERATED_KINDS)
"""The generated names as messages list them: ``gen-<seed> or gen-short-<seed>``."""


def generate_spec(
    seed: int,
    *,
    min_length_m: float = DEFAULT_MIN_LENGTH_M,
    max_length_m: float = DEFAULT_MAX_LENGTH_M,
    min_width_m: float = DEFAULT_MIN_WIDTH_M,
    max_width_m: float = DEFAULT_MAX_WIDTH_M,
    min_radius_m: float = DEFAULT_MIN_RADIUS_M,
    name: str | None = None,
) -> tuple[TrackSpec, Track]:
    """The spec of the track of ``seed`` and its built :class:`Track` (the spec is what
    ``tracks generate --save`` writes; the track is what everything else uses)."""
    _check_bounds(seed, min_length_m, max_length_m, min_width_m, max_width_m, min_radius_m)
    name = name or f"gen-{seed}"
    reasons: list[str] = []
    for attempt in range(MAX_ATTEMPTS):
        rng = np.random.default_rng(np.random.SeedSequence([seed, attempt]))
        spec = _candidate(rng, name, seed, min_length_m, max_length_m, min_width_m,
                          max_width_m, min_radius_m)
        if spec is None:
            continue
        try:
            track = build_track(spec, name, source=f"generated: seed {seed}, attempt {attempt}")
        except UserInputError as err:  # overlap (or, in theory, closure): try the next seed
            reasons.append(str(err))
            continue
        if min_length_m <= track.length_m <= max_length_m:
            return spec, track
    detail = f" (last: {reasons[-1]})" if reasons else ""
    raise UserInputError(
        f"generator: no valid track for seed {seed} in {MAX_ATTEMPTS} attempts with length "
        f"{min_length_m:g}-{max_length_m:g} m, width {min_width_m:g}-{max_width_m:g} m, "
        f"min radius {min_radius_m:g} m{detail}"
    )


def generate_track(seed: int, **bounds: Any) -> Track:
    """The closed, non-overlapping track ``gen-<seed>``; same seed and bounds, same track.

    ``bounds`` are the keyword arguments of :func:`generate_spec` (length, width and radius
    limits, the name). Takes ~10-30 ms once highway-env is imported.
    """
    return generate_spec(seed, **bounds)[1]


def tight_corner_share(track: Track, radius_m: float = 40.0, window_m: float = 10.0) -> float:
    """Share of the lap whose centre line, its curvature averaged over ~``window_m``, bends
    tighter than ``radius_m``: what :data:`GENERATED_KINDS` compares kinds and tracks by."""
    step_m = float(np.diff(track.s_m).mean())
    window = max(1, int(window_m / step_m))
    bend = np.convolve(np.abs(track.curvature_1pm), np.ones(window) / window, mode="same")
    return float((bend > 1.0 / radius_m).mean())


def generated_name(prefix: str, seed: int) -> str:
    """The name ``<prefix>-<seed>`` that loads the generated track of that kind and seed."""
    return f"{prefix}-{seed}"


def generated_spec(prefix: str, seed: int, name: str | None = None) -> tuple[TrackSpec, Track]:
    """Spec and track of ``<prefix>-<seed>``, a kind in :data:`GENERATED_KINDS`, named so unless
    ``name`` is given (``tracks generate --save --name``)."""
    return generate_spec(seed, name=name or generated_name(prefix, seed),
                         **GENERATED_KINDS[prefix])


def generated_track(prefix: str, seed: int) -> Track:
    """The track ``<prefix>-<seed>`` of a kind in :data:`GENERATED_KINDS`."""
    return generated_spec(prefix, seed)[1]


def _check_bounds(
    seed: int, min_len: float, max_len: float, min_w: float, max_w: float, min_r: float
) -> None:
    """Refuse impossible requests up front instead of failing after MAX_ATTEMPTS tries."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not (
        0 <= seed <= MAX_SEED
    ):
        raise UserInputError(f"generator: seed must be an integer in 0..{MAX_SEED}, got {seed!r}")
    if not 300.0 <= min_len < max_len <= 50_000.0:
        raise UserInputError(
            f"generator: need 300 <= min length < max length <= 50000 m, got "
            f"{min_len:g}..{max_len:g}"
        )
    if not 3.0 <= min_w <= max_w <= 60.0:
        raise UserInputError(
            f"generator: need 3 <= min width <= max width <= 60 m, got {min_w:g}..{max_w:g}"
        )
    if not max_w / 2.0 < min_r <= 0.5 * MAX_CORNER_RADIUS_M:
        raise UserInputError(
            f"generator: min radius {min_r:g} m must exceed half the max width ({max_w / 2:g} m)"
            f" and be at most {0.5 * MAX_CORNER_RADIUS_M:g} m"
        )


def _candidate(
    rng: np.random.Generator, name: str, seed: int, min_len: float, max_len: float,
    min_w: float, max_w: float, min_r: float,
) -> TrackSpec | None:
    """One random attempt, or None when its polygon cannot carry the required corners."""
    n = int(rng.integers(7, 14))
    # Sorted angles with a minimum gap, so no two vertices crowd one side.
    gaps = rng.uniform(0.5, 1.5, n)
    angles = np.cumsum(gaps / gaps.sum() * 2.0 * math.pi) + rng.uniform(0, 2 * math.pi)
    dist = rng.uniform(0.55, 1.0, n)
    dents = rng.random(n) < 0.25
    dist[dents] *= rng.uniform(0.45, 0.75, int(dents.sum()))
    pts = np.column_stack([dist * np.cos(angles), dist * np.sin(angles)])
    stretch = rng.uniform(1.0, 1.9)
    axis = rng.uniform(0, math.pi)
    rot = np.array([[math.cos(axis), -math.sin(axis)], [math.sin(axis), math.cos(axis)]])
    pts = pts @ rot.T
    pts[:, 0] *= stretch
    if rng.random() < 0.5:  # clockwise laps too
        pts = pts[::-1].copy()

    edge_vec = np.roll(pts, -1, axis=0) - pts  # edge i runs from vertex i to vertex i+1
    edge_len = np.hypot(edge_vec[:, 0], edge_vec[:, 1])
    head = np.arctan2(edge_vec[:, 1], edge_vec[:, 0])
    # Exterior angle at vertex i: from edge i-1's heading to edge i's.
    turn = np.angle(np.exp(1j * (head - np.roll(head, 1))))
    if np.any(np.abs(np.degrees(turn)) > MAX_CORNER_DEG):
        return None
    total = float(turn.sum())
    if abs(abs(total) - 2 * math.pi) > 1e-6:  # not a simple polygon after all
        return None

    width = float(np.round(rng.uniform(min_w, max_w) * 2.0) / 2.0)
    # Log-uniform radii: as many hairpins (12-40 m) as fast sweepers (100-300 m); the room
    # each polygon edge offers caps them below.
    radii = np.exp(rng.uniform(math.log(min_r), math.log(MAX_CORNER_RADIUS_M), n))
    target = rng.uniform(min_len + 0.03 * (max_len - min_len), max_len - 0.03 * (max_len - min_len))

    tan_half = np.tan(np.abs(turn) / 2.0)
    # Lap length = scale * perimeter - sum(2 R tan(t/2) - R |t|): solve for the scale.
    saving = float(np.sum(2.0 * radii * tan_half - radii * np.abs(turn)))
    scale = (target + saving) / float(edge_len.sum())
    edges = edge_len * scale
    # Each edge gives at most half of what is left after MIN_STRAIGHT_M to each of its corners.
    room = (np.minimum(edges, np.roll(edges, 1)) - MIN_STRAIGHT_M) / 2.0
    cap = np.where(tan_half > 1e-9, room / np.maximum(tan_half, 1e-12), np.inf)
    radii = np.minimum(radii, cap)
    if np.any(radii < min_r):
        return None
    tangent = radii * tan_half
    straights = edges - tangent - np.roll(tangent, -1)  # edge i: corner i start, corner i+1 end
    if np.any(straights < MIN_STRAIGHT_M - 1e-9):
        return None

    # Lap order: corner i, then straight i (edge i), for i = 0..n-1.
    pieces: list[SegmentSpec] = []
    for i in range(n):
        pieces.append(SegmentSpec("arc", radius_m=float(radii[i]),
                                  angle_deg=float(math.degrees(turn[i]))))
        pieces.append(SegmentSpec("straight", length_m=float(straights[i])))
    longest = int(np.argmax(straights))
    first = 2 * longest + 1
    cut = 0.4 * float(straights[longest])
    ordered = (
        [SegmentSpec("straight", length_m=float(straights[longest]) - cut)]
        + pieces[first + 1:] + pieces[:first]
        + [SegmentSpec("straight", length_m=cut)]
    )
    return TrackSpec(
        name=name, width_left_m=width / 2.0, width_right_m=width / 2.0, segments=ordered,
        description=f"procedural track, seed {seed}",
    )
