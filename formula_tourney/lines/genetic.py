"""Genetic racing line after Cardamone et al. 2010: a GA over offsets at control points.

A genome is one lateral offset per control point (about every ``spacing_m`` metres), bounded
by the track width minus a margin; the line is the periodic C2 spline through the control
points (``mincurv.spline_offsets``), so every candidate is smooth without clipping kinks.
Fitness is the quasi-steady-state lap time of that line for our car: a few milliseconds per
candidate, where a lap of the follower in the simulator costs seconds. The best ``final_k``
distinct candidates are then re-timed by an actual driver (the follower, passed in as
``driver``) and the fastest clean one wins, so the genetic bot's line is chosen by a driven
lap as in the paper's baseline. Everything random comes from one ``numpy`` Generator seeded
by ``seed``: the same seed gives the same line.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.lines.mincurv import DEFAULT_MARGIN_M, offset_bounds, spline_offsets
from formula_tourney.lines.speed_profile import CarModel, speed_profile
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.track import Track

BULGE_PENALTY_S_PER_M = 10.0

Driver = Callable[[Track, np.ndarray], dict]
"""Drives a line (offsets per sample) and returns the follower's result dict (``best_lap_s``,
``damage``, ``finished``): how the final candidates are re-timed in the simulator."""


@dataclass
class GeneticResult:
    """The chosen line and the search's record (for the CLI, docs and tests)."""

    offsets_m: np.ndarray
    surrogate_lap_s: float
    driven_lap_s: float
    history_best_s: list[float] = field(default_factory=list)
    finalists: list[dict] = field(default_factory=list)
    evaluations: int = 0
    seconds: float = 0.0


def control_indices(track: Track, spacing_m: float) -> np.ndarray:
    """Control points every ``spacing_m`` on straights, denser in corners.

    Density grows as ``1 + 50 |k|`` (smoothed over 20 m): about 5x on a 12 m hairpin. With an
    even 30 m spacing a hairpin got one or two points, the spline through them bulged a metre
    past the margin, and no candidate could be driven on ``technical`` (measured).
    """
    spacing = track.length_m / track.n
    half = max(int(round(10.0 / spacing)), 1)
    kappa = np.abs(track.curvature_1pm)
    padded = np.concatenate([kappa[-half:], kappa, kappa[:half]])
    smooth = np.convolve(padded, np.ones(2 * half + 1) / (2 * half + 1), mode="valid")
    weight = np.cumsum((1.0 + 50.0 * smooth) * spacing)
    n_ctrl = max(int(round(weight[-1] / spacing_m)), 12)
    targets = np.arange(n_ctrl) * weight[-1] / n_ctrl
    return np.unique(np.searchsorted(weight, targets).clip(0, track.n - 1))


class _Problem:
    """Control points and the genome -> line -> QSS lap time map."""

    def __init__(self, track: Track, car: CarParams, spacing_m: float, margin_m: float):
        self.track = track
        self.car = car
        self.model = CarModel.from_car(car)
        self.idx = control_indices(track, spacing_m)
        lower, upper = offset_bounds(track, margin_m)
        self.lower_all, self.upper_all = lower, upper
        self.lower, self.upper = lower[self.idx], upper[self.idx]
        self.margin_m = margin_m
        heading = track.heading_rad[self.idx]
        self.nx, self.ny = -np.sin(heading), np.cos(heading)

    def raw_line(self, genome: np.ndarray) -> np.ndarray:
        t = self.track
        px = t.x_m[self.idx] + self.nx * genome
        py = t.y_m[self.idx] + self.ny * genome
        return spline_offsets(t, t.s_m[self.idx], px, py, genome)

    def line(self, genome: np.ndarray) -> np.ndarray:
        # The spline can bulge past a bound between control points; half the margin is kept
        # as hard room (the same rule as the min-curvature line).
        t = self.track
        return np.clip(self.raw_line(genome), -t.width_right_m + 0.5 * self.margin_m,
                       t.width_left_m - 0.5 * self.margin_m)

    def lap_s(self, genome: np.ndarray) -> float:
        """QSS lap time plus 10 s per metre the spline bulges past the margin: unpenalised,
        the search used those bulges (1 m from the edge) and its best lines left the track
        when driven on `technical` (measured)."""
        raw = self.raw_line(genome)
        bulge = max(float(np.max(raw - self.upper_all)), float(np.max(self.lower_all - raw)), 0.0)
        lap = speed_profile(self.track, self.line(genome), self.car, self.model).lap_time_s
        return lap + BULGE_PENALTY_S_PER_M * bulge


def genetic_line(
    track: Track,
    car: CarParams | None = None,
    *,
    seed: int = 0,
    population: int = 24,
    generations: int = 40,
    spacing_m: float = 30.0,
    margin_m: float = DEFAULT_MARGIN_M,
    mutation_m: float = 0.6,
    elite: int = 2,
    final_k: int = 3,
    seed_offsets_m: np.ndarray | None = None,
    driver: Driver | None = None,
) -> GeneticResult:
    """Evolve a line; with ``driver`` the best ``final_k`` are re-timed by driving them.

    ``seed_offsets_m`` (e.g. the min-curvature line) seeds part of the first population, as
    Cardamone et al. seed theirs with known lines; the rest is random within the bounds.
    """
    if population < 4 or generations < 1 or not 0 <= elite < population or final_k < 1:
        raise UserInputError(
            "genetic line needs population >= 4, generations >= 1, 0 <= elite < population, "
            "final_k >= 1"
        )
    if spacing_m < 5.0:
        raise UserInputError(f"control point spacing must be >= 5 m, got {spacing_m}")
    car = car or CarParams()
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    prob = _Problem(track, car, spacing_m, margin_m)
    lo, hi = prob.lower, prob.upper
    span = np.maximum(hi - lo, 1e-9)
    n_genes = prob.idx.size

    pop = lo + rng.random((population, n_genes)) * span
    pop[0] = np.clip(0.0, lo, hi)
    if seed_offsets_m is not None:
        base = np.clip(np.asarray(seed_offsets_m, dtype=float)[prob.idx], lo, hi)
        pop[1] = base
        n_seeded = max(population // 3, 1)
        for i in range(2, 2 + n_seeded):
            if i < population:
                pop[i] = np.clip(base + rng.normal(0.0, mutation_m, n_genes), lo, hi)
    fitness = np.array([prob.lap_s(g) for g in pop])
    evaluations = population
    history = [float(fitness.min())]
    for gen in range(generations):
        order = np.argsort(fitness)
        children = [pop[i].copy() for i in order[:elite]]
        # Mutation shrinks over the run: explore first, then refine around the best lines.
        sigma = mutation_m * (1.0 - 0.8 * gen / max(generations - 1, 1))
        while len(children) < population:
            a = _tournament(rng, fitness)
            b = _tournament(rng, fitness)
            # Blend crossover per gene, then sparse Gaussian mutation: neighbouring control
            # points are coupled through the spline, so small local changes are what improve.
            w = rng.random(n_genes)
            child = w * pop[a] + (1.0 - w) * pop[b]
            mask = rng.random(n_genes) < 0.2
            child = child + mask * rng.normal(0.0, sigma, n_genes)
            children.append(np.clip(child, lo, hi))
        pop = np.array(children)
        fitness = np.concatenate([fitness[order[:elite]],
                                  [prob.lap_s(g) for g in pop[elite:]]])
        evaluations += population - elite
        history.append(float(fitness.min()))

    order = np.argsort(fitness)
    finalists: list[dict] = []
    seen: list[np.ndarray] = []
    for i in order:
        if any(np.max(np.abs(pop[i] - g)) < 1e-6 for g in seen):
            continue
        seen.append(pop[i])
        finalists.append({"genome": pop[i], "surrogate_lap_s": float(fitness[i])})
        if len(finalists) == final_k:
            break
    chosen = finalists[0]
    driven = float("nan")
    if driver is not None:
        # Re-time the finalists; if none laps cleanly, keep going down the ranking (up to
        # 3 x final_k candidates) rather than hand back a line the follower cannot drive.
        ranked = []
        for i in order:
            if any(np.max(np.abs(pop[i] - r["genome"])) < 1e-6 for r in ranked):
                continue
            ranked.append({"genome": pop[i], "surrogate_lap_s": float(fitness[i])})
        timed = []
        finalists = []
        for cand in ranked[: 3 * final_k]:
            result = driver(track, prob.line(cand["genome"]))
            clean = bool(result.get("finished")) and float(result.get("damage", 0.0)) == 0.0
            cand["driven_lap_s"] = float(result.get("best_lap_s", float("nan"))) if clean \
                else float("nan")
            finalists.append(cand)
            if clean:
                timed.append(cand)
            if len(finalists) >= final_k and timed:
                break
        if timed:
            chosen = min(timed, key=lambda c: c["driven_lap_s"])
            driven = chosen["driven_lap_s"]
    return GeneticResult(
        offsets_m=prob.line(chosen["genome"]),
        surrogate_lap_s=chosen["surrogate_lap_s"],
        driven_lap_s=driven,
        history_best_s=history,
        finalists=[{k: v for k, v in c.items() if k != "genome"} for c in finalists],
        evaluations=evaluations,
        seconds=time.perf_counter() - t0,
    )


def _tournament(rng: np.random.Generator, fitness: np.ndarray, size: int = 3) -> int:
    picks = rng.integers(0, fitness.size, size)
    return int(picks[np.argmin(fitness[picks])])
