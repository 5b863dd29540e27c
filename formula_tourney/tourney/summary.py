"""The tournament's state as plain data, read from its index: what ``run`` returns and prints."""

from __future__ import annotations

from typing import Any

from formula_tourney.tourney.kinds import BASELINE, KINDS
from formula_tourney.tourney.plan import PlannedPart
from formula_tourney.tourney.store import Store


def collect_results(store: Store, name: str, planned: list[PlannedPart]) -> dict[str, Any]:
    """Parts with rankings, the reference limit of their key track and what each job kind
    shows of them (``JobKind.show``: training jobs per status, baseline drives, a race part's
    series), failed jobs of every kind, and the general models chosen."""
    parts = []
    drives = store.rows(BASELINE.name)  # the reference limit of a part's key track
    for item in planned:
        part = item.part.name
        row = store.part(part) or {"part": part, "status": "pending"}
        limits = [b["reference_limit_s"] for b in drives
                  if b["part"] == part and b["track"] == item.key_track
                  and b.get("reference_limit_s") is not None]  # fmt: skip
        if not limits:  # another part may have driven the same track
            limits = [b["reference_limit_s"] for b in drives
                      if b["track"] == item.key_track and b.get("reference_limit_s") is not None]
        entry = {
            "part": part, "study": row.get("study"), "status": row.get("status"),
            "train_track": item.key_track, "reference_limit_s": limits[0] if limits else None,
            "reason": row.get("reason"), "entrants": row.get("entrants") or [],
            "promoted": row.get("promoted") or {}, "ranking": row.get("ranking") or [],
        }  # fmt: skip
        for kind in KINDS.values():
            entry.update(kind.show(item, store.rows(kind.name, part), store.root))
        parts.append(entry)
    failures = [{"job_id": r["job_id"], "kind": r["kind"], "reason": r["reason"],
                 "attempts": r["attempts"]}
                for r in store.rows() if r["status"] == "failed"]  # fmt: skip
    general = store.general_models()
    return {
        "tournament": name, "results": str(store.root), "parts": parts, "failures": failures,
        "general_models": general.to_dict(orient="records") if not general.empty else [],
    }
