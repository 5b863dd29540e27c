"""Promotion: who goes from a finished part to the next, ranked by lap time over seeds.

The paper selects by average best lap time (aLT: mean over seeds of each seed's best clean lap),
keeps the best of each algorithm family, and on the technical track the best overall. Lap time,
never return: the paper's reward ranks laps poorly (docs/agents.md, the reward sections). A seed
that failed or never completed a clean lap counts against the finish rate, not in the mean.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from formula_tourney.tourney.spec import Promotion


def rank_entrants(jobs: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per entrant: aLT, bLT, finish rate, seeds done/failed; sorted best first.

    ``jobs`` are index rows (entrant, variant, family, status, best_lap_s). Entrants without a
    clean lap sort last; ties break on bLT, then name, so the ranking is deterministic.
    """
    groups: dict[str, dict[str, Any]] = {}
    for job in jobs:
        row = groups.setdefault(job["entrant"], {
            "entrant": job["entrant"], "variant": job["variant"], "family": job["family"],
            "seeds": 0, "done": 0, "failed": 0, "laps": [],
        })
        row["seeds"] += 1
        if job["status"] == "done":
            row["done"] += 1
        elif job["status"] == "failed":
            row["failed"] += 1
        lap = job.get("best_lap_s")
        if job["status"] == "done" and lap is not None and not math.isnan(float(lap)):
            row["laps"].append(float(lap))
        dist = job.get("test_distance_m")
        if job["status"] == "done" and dist is not None and not math.isnan(float(dist)):
            row.setdefault("distances", []).append(float(dist))
    ranking = []
    for row in groups.values():
        laps = row.pop("laps")
        distances = row.pop("distances", [])
        row["distance_m"] = sum(distances) / len(distances) if distances else None
        row["finished_seeds"] = len(laps)
        row["finish_rate"] = len(laps) / row["seeds"] if row["seeds"] else 0.0
        row["aLT"] = sum(laps) / len(laps) if laps else None
        row["bLT"] = min(laps) if laps else None
        ranking.append(row)
    ranking.sort(key=lambda r: (r["aLT"] is None, r["aLT"] or 0.0, r["bLT"] or 0.0, r["entrant"]))
    return ranking


def promote(ranking: list[dict[str, Any]], rule: Promotion) -> tuple[list[str], list[dict]]:
    """Apply a promotion rule to a ranking; returns (promoted variants, ranking with reasons).

    Eligible: a clean lap in at least ``min_finish_rate`` of the seeds (and at least one).
    Then the best per family (if asked), then the k best variants by ``rule.metric``. Entrants are
    <variant>-<setup>; the next part gets variants (deduplicated, best first) and declares its
    own setups, as the paper's part 3 takes the best algorithm and adds LAC.
    """
    metric = rule.metric

    def key(row: dict[str, Any]) -> tuple:
        value = row[metric]
        other = row["bLT" if metric == "aLT" else "aLT"]
        return (value is None, value or 0.0, other or 0.0, row["entrant"])

    rows = [dict(r) for r in sorted(ranking, key=key)]
    eligible = []
    below = []
    for row in rows:
        if row[metric] is None:
            row["decision"] = "no clean lap"
            below.append(row)
        elif row["finish_rate"] < rule.min_finish_rate:
            row["decision"] = f"finish rate {row['finish_rate']:.2f} < {rule.min_finish_rate:g}"
            below.append(row)
        else:
            eligible.append(row)
    if rule.unfinished == "by_distance":
        # Motorsport classifies cars that did not finish by the distance they covered.
        classified = [r for r in below if r.get("distance_m") is not None]
        classified.sort(key=lambda r: (-r["distance_m"], r["entrant"]))
        for row in classified:
            row["decision"] += f"; classified by distance {row['distance_m']:.0f} m"
        eligible += classified
    chosen = eligible
    if rule.best_per_family:
        seen: set[str] = set()
        chosen = []
        for row in eligible:
            if row["family"] in seen:
                _decide(row, f"not best of family {row['family']}")
                continue
            seen.add(row["family"])
            chosen.append(row)
    variants: list[str] = []
    via: dict[str, str] = {}
    for row in chosen:
        if row["variant"] in via:
            _decide(row, f"variant promoted via {via[row['variant']]}")
        elif rule.top_k is not None and len(variants) >= rule.top_k:
            _decide(row, f"outside top {rule.top_k}")
        else:
            _decide(row, "promoted")
            via[row["variant"]] = row["entrant"]
            variants.append(row["variant"])
    return variants, rows


def _decide(row: dict[str, Any], text: str) -> None:
    """Record a decision, after the classification note of an unfinished entrant if any."""
    row["decision"] = f"{row['decision']}; {text}" if row.get("decision") else text
