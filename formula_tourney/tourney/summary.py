"""The tournament's state as plain data, read from its index: what ``run`` returns and prints."""

from __future__ import annotations

from typing import Any

from formula_tourney.results.folder import RaceFolder
from formula_tourney.tourney.plan import PlannedPart
from formula_tourney.tourney.store import Store


def collect_results(store: Store, name: str, planned: list[PlannedPart]) -> dict[str, Any]:
    """Parts with rankings and job counts (a race part: its series' status and how many of its
    races are on disk), failures (training jobs, baseline drives, race series), baselines and
    the general models chosen."""
    parts = []
    baselines = store.baseline_rows()
    for item in planned:
        part = item.part.name
        row = store.part(part) or {"part": part, "status": "pending"}
        jobs = store.job_rows(part)
        limits = [b["reference_limit_s"] for b in baselines
                  if b["part"] == part and b["track"] == item.key_track
                  and b["reference_limit_s"] is not None]  # fmt: skip
        if not limits:  # another part may have driven the same track
            limits = [b["reference_limit_s"] for b in baselines
                      if b["track"] == item.key_track and b["reference_limit_s"] is not None]
        parts.append({
            "part": part, "study": row.get("study"), "status": row.get("status"),
            "train_track": item.key_track, "reference_limit_s": limits[0] if limits else None,
            "reason": row.get("reason"), "entrants": row.get("entrants") or [],
            "promoted": row.get("promoted") or {}, "ranking": row.get("ranking") or [],
            "jobs": {s: sum(j["status"] == s for j in jobs)
                     for s in ("done", "failed", "pending", "running")},
            "race": _race(store, part) if item.part.kind == "race" else None,
        })  # fmt: skip
    failures = [{"job_id": r["job_id"], "kind": "train", "reason": r["reason"],
                 "attempts": r["attempts"]}
                for r in store.job_rows() if r["status"] == "failed"]  # fmt: skip
    failures += [{"job_id": r["path"], "kind": "baseline", "reason": r["reason"],
                  "attempts": None}
                 for r in baselines if r["status"] == "failed"]  # fmt: skip
    failures += [{"job_id": r["path"], "kind": "race", "reason": r["reason"],
                  "attempts": r["attempts"]}
                 for r in store.race_rows() if r["status"] == "failed"]  # fmt: skip
    general = store.general_models()
    return {
        "tournament": name, "results": str(store.root), "parts": parts,
        "failures": failures, "baselines": baselines,
        "general_models": general.to_dict(orient="records") if not general.empty else [],
    }


def _race(store: Store, part: str) -> dict[str, Any]:
    """A race part's series: the index's status, and the race files on disk."""
    row = store.race(part) or {"status": "waiting", "races": None, "entrants": [],
                               "path": None, "reason": None}
    raced = len(RaceFolder(store.root / row["path"]).race_numbers()) if row["path"] else 0
    return {"status": row["status"], "reason": row["reason"], "races": row["races"],
            "raced": raced, "entrants": row["entrants"] or [], "path": row["path"]}
