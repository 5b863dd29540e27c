"""Sequential runs: seeds added in waves where the claims are still undecided.

A tournament with an ``[adaptive]`` table (``tourney.spec.Adaptive``, or ``run --budget-cpu-h``)
starts every entrant of a training part at ``min_seeds``. Each time every queued job has ended
(a *wave*), the claims are read again from the results folder by a *judge* (the report's
claims, ``report.claims.judge``, handed in by the command line: the tournament layer reads no
report), each comparison with its anytime-valid confidence sequence (``claims.sequential``), so
reading after every wave keeps its 5 % error. Then :func:`allocate` chooses the next wave:

- only comparisons of undecided claims that are themselves undecided ask for seeds; a claim
  is decided when its sequential verdict is supported or contradicted;
- each comparison is projected to the pairs its CS needs in all if the values seen so far
  came again in the same order (``claims.sequential.projected_pairs``: exact for the betting
  CS, so a comparison won in every pair needs 7, not the more a 1/sqrt(n) model would ask
  for), and priced at the runs that takes (each side's entrants' mean measured job seconds);
- a claim is decided by any one contradicted comparison or by all supported
  (``report.claims.evidence.overall``), so it is priced at the cheaper of its cheapest
  comparison heading to contradicted and the sum of its comparisons when all head to
  supported; only the comparisons of that path get seeds;
- one more *pair* of a comparison (the i-th run of A against the i-th of B) needs a run of the
  side with fewer runs (both when even; a bot side none), of that side's entrant with the
  fewest seeds below ``max_seeds`` in a part still open;
- the wave takes the claim with the cheapest path first (the most decisions per CPU-second),
  one pair at a time, and stops funding a comparison once it holds its projected pairs, until
  the wave holds ``wave_seeds`` jobs;
- a claim that is projected never to decide (its mean at the threshold, or past
  ``claims.sequential.PROJECTION_LIMIT`` pairs, or past ``max_seeds``) or to need more than
  the budget left gets no seeds: spending on it would leave the budget spent and the claim
  open. Projections from the first few pairs are rough; each wave projects again.

Promotion waits for its source part to be *settled*: no undecided comparison can still give
seeds to it (every one reading it is decided, at ``max_seeds`` or off every claim's path), or
no wave can be added; a part no other part promotes from stays open until the run stops. A
wave that adds nothing releases every source part (its promotion runs, and the promoted
parts start at ``min_seeds``); when nothing is left to run the run stops, with its reason:
every claim decided, the budget spent, the undecided claims out of the budget's reach, or
their entrants at ``max_seeds`` (or without runs to read). The budget counts every job's
seconds (``wall_s`` of one-thread workers); the ``min_seeds`` runs of every part always run,
so the budget limits the seeds added beyond them.

Seeds added later are new jobs with the next seed numbers (``tourney.plan.Planner.seeds``),
so the same seed is always the same job. Every decision is written atomically to
``adaptive.json`` (``results.layout.ADAPTIVE_FILE``) before the wave's jobs are queued: a run
killed in the middle of a wave resumes with the same seeds, and reads the same verdicts at
them as a run that was never interrupted.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from formula_tourney.errors import UserInputError
from formula_tourney.results.layout import ADAPTIVE_FILE
from formula_tourney.safeio import atomic_write_json
from formula_tourney.tourney.plan import Planner
from formula_tourney.tourney.spec import Adaptive
from formula_tourney.tourney.store import Store

SUPPORTED, CONTRADICTED, INCONCLUSIVE = "supported", "contradicted", "inconclusive"
DECIDED = (SUPPORTED, CONTRADICTED)
STOP_DECIDED = "every claim is decided"
STOP_BUDGET = "the CPU budget is spent"
STOP_MAX_SEEDS = "the undecided claims need more seeds than max_seeds allows"
STOP_NO_RUNS = "the undecided claims have no runs to read"
STOP_OUT_OF_REACH = "the undecided claims are projected to need more than the budget left"


def target_key(part: str, entrant: str) -> str:
    """``part/entrant``: how a target is written in ``adaptive.json``."""
    return f"{part}/{entrant}"


@dataclass(frozen=True)
class Look:
    """One comparison of a claim as read after a wave: who each side's runs are (``part``,
    ``entrant``; none for a bot), how many runs each has, its confidence sequence, the pairs
    it is projected to need in all (``claims.sequential.pairs_to_decide``: None where the
    values seen so far, repeated, never decide) and the verdict its mean heads to."""

    claim: str
    label: str
    verdict: str
    a_targets: tuple[tuple[str, str], ...]
    b_targets: tuple[tuple[str, str], ...]
    n_a: int
    n_b: int
    pairs: int
    mean: float
    low: float
    high: float
    needed: int | None = None
    heading: str = INCONCLUSIVE

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["a_targets"] = [target_key(*t) for t in self.a_targets]
        out["b_targets"] = [target_key(*t) for t in self.b_targets]
        return out


@dataclass(frozen=True)
class ClaimLook:
    """A claim as read after a wave: its sequential verdict and its comparisons."""

    claim: str
    verdict: str
    looks: tuple[Look, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {
            "claim": self.claim,
            "verdict": self.verdict,
            "comparisons": [x.to_json() for x in self.looks],
        }


Judge = Callable[[Path], list[ClaimLook]]
"""Reads a results folder's claims (``report.claims.judge.judge``)."""


@dataclass
class Wave:
    """What :func:`allocate` chose: runs added per (part, entrant), the pairs it bought and,
    when it added nothing, why."""

    added: dict[tuple[str, str], int] = field(default_factory=dict)
    cpu_s: float = 0.0
    picks: list[dict[str, Any]] = field(default_factory=list)
    reason: str | None = None
    open_parts: set[str] = field(default_factory=set)
    """Parts an undecided comparison could still give seeds to (not settled)."""


def _side_pick(
    targets: tuple[tuple[str, str], ...],
    seeds: dict[tuple[str, str], int],
    design: Adaptive,
    closed: set[str],
) -> tuple[str, str] | None:
    """The entrant of a side that gets its next run: the one with the fewest seeds below
    max_seeds in an open part (ties by name); None if none can."""
    ok = [t for t in sorted(targets) if t[0] not in closed
          and seeds.get(t, design.min_seeds) < design.max_seeds]  # fmt: skip
    return min(ok, key=lambda t: seeds.get(t, design.min_seeds)) if ok else None


def _needs(look: Look, n_a: int, n_b: int) -> list[str]:
    if not look.a_targets:
        return ["b"]
    if not look.b_targets:
        return ["a"]
    return ["a"] if n_a < n_b else ["b"] if n_b < n_a else ["a", "b"]


@dataclass
class _Open:
    """An undecided comparison while a wave is chosen: its runs and pairs so far (the wave's
    picks included) and the pairs it is projected to need."""

    look: Look
    n_a: int
    n_b: int
    pairs: int

    @property
    def left(self) -> int:
        return max(0, (self.look.needed or 0) - self.pairs)

    def cost_s(
        self,
        cost: Callable[[tuple[str, str]], float],
        seeds: dict[tuple[str, str], int],
        design: Adaptive,
        closed: set[str],
    ) -> float:
        """CPU-seconds of the runs it still needs to reach its projected pairs (a side's
        runs at its entrants' mean cost); inf where it never decides at its observed values
        or its entrants have no room left below max_seeds."""
        if self.look.needed is None:
            return math.inf
        total = 0.0
        for targets, have in ((self.look.a_targets, self.n_a), (self.look.b_targets, self.n_b)):
            runs = max(0, self.look.needed - have) if targets else 0
            if not runs:
                continue
            room = sum(max(0, design.max_seeds - seeds.get(t, design.min_seeds))
                       for t in targets if t[0] not in closed)  # fmt: skip
            if runs > room:
                return math.inf
            total += runs * sum(max(cost(t), 1e-3) for t in targets) / len(targets)
        return total


def _path(
    claim: ClaimLook,
    opened: dict[int, _Open],
    price: Callable[[_Open], float],
) -> tuple[float, list[_Open]]:
    """The cheaper way to decide a claim and its CPU-seconds: one comparison heading to
    contradicted (any contradicted comparison decides it, ``report.claims.evidence.overall``)
    or every undecided comparison to supported (inf if one heads elsewhere or has no runs)."""
    mine = [opened[id(x)] for x in claim.looks if id(x) in opened]
    contra = [(price(o), o) for o in mine if o.look.heading == CONTRADICTED]
    best: tuple[float, list[_Open]] = min(
        ((c, [o]) for c, o in contra), key=lambda p: p[0], default=(math.inf, [])
    )
    unsettled = [x for x in claim.looks if x.verdict != SUPPORTED]
    if all(id(x) in opened and opened[id(x)].look.heading == SUPPORTED for x in unsettled):
        support = sum(price(o) for o in mine)
        if support < best[0] or not best[1]:
            best = (support, mine)
    return best


def allocate(
    claims: list[ClaimLook],
    seeds: dict[tuple[str, str], int],
    cost_s: Callable[[tuple[str, str]], float],
    design: Adaptive,
    budget_left_s: float,
    closed: set[str],
) -> Wave:
    """The next wave (see the module's docstring for the rule); ``seeds``: each entrant's
    seeds now; ``cost_s``: an entrant's CPU-seconds per run; ``closed``: parts that take no
    more seeds."""
    wave = Wave()
    undecided = [c for c in claims if c.verdict not in DECIDED]
    opened = {id(x): _Open(x, x.n_a, x.n_b, x.pairs) for c in undecided for x in c.looks
              if x.verdict == INCONCLUSIVE and x.pairs >= 1}  # fmt: skip
    if not opened:
        wave.reason = STOP_NO_RUNS if undecided else STOP_DECIDED
        return wave
    tentative = dict(seeds)
    blocked: set[str] = set()

    def price(o: _Open) -> float:
        return o.cost_s(cost_s, tentative, design, closed)

    while sum(wave.added.values()) < design.wave_seeds:
        best: tuple[float, ClaimLook, list[_Open]] | None = None
        for claim in undecided:
            cost, path = _path(claim, opened, price)
            if path and cost <= 0.0:
                continue  # projected decided by the runs this wave has chosen
            if math.isinf(cost):
                blocked.add(STOP_MAX_SEEDS if path and all(o.look.needed for o in path)
                            else STOP_OUT_OF_REACH)  # fmt: skip
                continue
            left_s = budget_left_s - wave.cpu_s
            if cost > left_s:
                one_run_s = min(max(cost_s(t), 1e-3) for o in path
                                for t in (*o.look.a_targets, *o.look.b_targets))  # fmt: skip
                blocked.add(STOP_BUDGET if one_run_s > left_s else STOP_OUT_OF_REACH)
                continue
            if best is None or cost < best[0]:
                best = (cost, claim, path)
        if best is None:
            break
        path_cost, claim, path = best
        o = max((x for x in path if x.left > 0), key=lambda x: x.left)
        picks = []
        for side in _needs(o.look, o.n_a, o.n_b):
            pick = _side_pick(
                o.look.a_targets if side == "a" else o.look.b_targets, tentative, design, closed
            )
            if pick is None:
                break
            picks.append(pick)
        cost = sum(max(cost_s(t), 1e-3) for t in picks)
        if len(picks) < len(_needs(o.look, o.n_a, o.n_b)) or cost > budget_left_s - wave.cpu_s:
            blocked.add(STOP_BUDGET if picks else STOP_MAX_SEEDS)
            break
        o.pairs += 1
        for t in picks:
            tentative[t] = tentative.get(t, design.min_seeds) + 1
            wave.added[t] = wave.added.get(t, 0) + 1
            if t in o.look.a_targets:
                o.n_a += 1
            else:
                o.n_b += 1
        wave.cpu_s += cost
        wave.picks.append(
            {
                "claim": claim.claim,
                "comparison": o.look.label,
                "runs": [target_key(*t) for t in picks],
                "value_per_cpu_s": 1.0 / path_cost,
                "cpu_s": cost,
                "projected_pairs": o.look.needed,
            }
        )
    for claim in undecided:
        cost, path = _path(claim, opened, price)
        if math.isfinite(cost):
            for o in path:
                for t in (*o.look.a_targets, *o.look.b_targets):
                    if t[0] not in closed and tentative.get(t, design.min_seeds) < design.max_seeds:
                        wave.open_parts.add(t[0])
    if not wave.added:
        cheapest_run_s = min(max(cost_s(t), 1e-3) for o in opened.values()
                             for t in (*o.look.a_targets, *o.look.b_targets))  # fmt: skip
        if cheapest_run_s > budget_left_s:
            blocked.add(STOP_BUDGET)
        wave.reason = next((r for r in (STOP_BUDGET, STOP_OUT_OF_REACH, STOP_MAX_SEEDS)
                            if r in blocked), STOP_MAX_SEEDS)  # fmt: skip
        wave.open_parts.clear()
    return wave


def _target(key: str) -> tuple[str, str]:
    """``part/entrant`` back to its pair (a part name holds no '/')."""
    part, _, entrant = key.partition("/")
    return part, entrant


class AdaptiveRun:
    """The waves of one sequential run: restores its seeds from ``adaptive.json``, holds parts
    open, chooses each wave and records it."""

    def __init__(self, planner: Planner, root: Path, judge: Judge) -> None:
        if planner.spec.adaptive is None:
            raise ValueError("AdaptiveRun needs a tournament with an [adaptive] design")
        self.planner = planner
        self.design: Adaptive = planner.spec.adaptive
        self.root = Path(root)
        self.path = self.root / ADAPTIVE_FILE
        self.judge = judge
        self.state: dict[str, Any] = {
            "design": self.design.model_dump(),
            "waves": [],
            "settled": [],
            "stopped": None,
        }
        if self.path.is_file():
            try:
                self.state = json.loads(self.path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as err:
                raise UserInputError(
                    f"{self.path}: unreadable ({err}); move it aside to "
                    "start the sequential run's decisions afresh"
                ) from None
        self.state["design"] = self.design.model_dump()
        seeds = self.state["waves"][-1]["seeds"] if self.state["waves"] else {}
        planner.entrant_seeds = {_target(k): int(v) for k, v in seeds.items()}
        self.sources = {p.promoted_from for p in planner.spec.parts if p.promoted_from}
        self.trains = {p.name for p in planner.spec.parts if p.kind == "train"}

    @property
    def stopped(self) -> bool:
        return self.state["stopped"] is not None

    def holds(self, part: str) -> bool:
        """Whether a training part whose jobs have all ended must stay open for more seeds."""
        return (part in self.trains and not self.stopped
                and part not in set(self.state["settled"]))  # fmt: skip

    def _write(self) -> None:
        atomic_write_json(self.path, self.state)

    def _seeds(self) -> dict[tuple[str, str], int]:
        return dict(self.planner.entrant_seeds or {})

    def spent_s(self, store: Store) -> float:
        """CPU-seconds the run's jobs took so far (every kind; a job recovered from its
        folder without a time counts its training seconds)."""
        total = 0.0
        for row in store.rows():
            if row["status"] not in ("done", "failed"):
                continue
            wall = row.get("wall_s")
            if wall is None:
                wall = (row.get("result") or {}).get("train_seconds") or 0.0
            total += float(wall)
        return total

    def costs(self, store: Store) -> Callable[[tuple[str, str]], float]:
        """Mean measured seconds of one run of an entrant (else of its part, else of all)."""
        per: dict[tuple[str, str], list[float]] = {}
        for row in store.rows("train"):
            if row["status"] == "done" and row.get("wall_s"):
                per.setdefault((row["part"], row["entrant"]), []).append(float(row["wall_s"]))
        every = [v for vs in per.values() for v in vs]

        def cost(target: tuple[str, str]) -> float:
            mine = per.get(target) or [v for (p, _), vs in per.items() if p == target[0]
                                       for v in vs] or every or [1.0]  # fmt: skip
            return sum(mine) / len(mine)

        return cost

    def next_wave(self, store: Store, closed: set[str]) -> tuple[list[str], str | None]:
        """Read the claims, choose and record the next wave; returns the parts that got seeds
        (their jobs are then made again with the new seed numbers) and, if none, why."""
        if self.stopped:
            return [], self.state["stopped"]["reason"]
        claims = self.judge(self.root)
        budget_s = (
            self.design.budget_cpu_h * 3600.0 if self.design.budget_cpu_h is not None else math.inf
        )
        spent = self.spent_s(store)
        closed = closed | set(self.state["settled"])
        wave = allocate(
            claims, self._seeds(), self.costs(store), self.design, budget_s - spent, closed
        )
        seeds = self._seeds()
        for target, n in wave.added.items():
            seeds[target] = seeds.get(target, self.design.min_seeds) + n
        settled = set(self.state["settled"])
        settled |= {p for p in self.sources if p not in wave.open_parts}
        self.state["settled"] = sorted(settled)
        self.state["waves"].append({
            "wave": len(self.state["waves"]) + 1,
            "spent_cpu_s": spent, "budget_cpu_s": None if math.isinf(budget_s) else budget_s,
            "claims": [c.to_json() for c in claims],
            "added": {target_key(*t): n for t, n in sorted(wave.added.items())},
            "picks": wave.picks, "expected_cpu_s": wave.cpu_s, "reason": wave.reason,
            "seeds": {target_key(*t): n for t, n in sorted(seeds.items())},
        })  # fmt: skip
        self.planner.entrant_seeds = seeds
        self._write()  # before the wave's jobs are queued: a resume makes the same jobs
        return sorted({t[0] for t in wave.added}), wave.reason

    def finish(self, reason: str | None) -> None:
        """Nothing is left to run: record why the run stopped and release every part."""
        last = self.state["waves"][-1] if self.state["waves"] else {}
        self.state["stopped"] = {
            "reason": reason or STOP_DECIDED,
            "waves": len(self.state["waves"]),
            "claims": {c["claim"]: c["verdict"] for c in last.get("claims", [])},
        }
        self.state["settled"] = sorted(self.trains)
        self._write()
