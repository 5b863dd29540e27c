"""The sequential run's table: each claim's anytime-valid verdict after every wave, and why the run
stopped.

A sequential run (``[adaptive]``, ``tourney.adaptive``) writes its decisions to
``adaptive.json`` (``results.layout.ADAPTIVE_FILE``): per wave the claims as read, the runs it
added and the seeds per entrant after it, and at the end the reason it stopped. This table
shows them as they were decided (it recomputes nothing); a tournament run with fixed seeds has
no such file and no table.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from formula_tourney.report.table_model import DASH, ReportTable
from formula_tourney.results.layout import ADAPTIVE_FILE

GROUP = "waves"


def read_waves(root: str | Path) -> dict[str, Any] | None:
    """The run's ``adaptive.json``, None where it has none (or it cannot be read)."""
    path = Path(root) / ADAPTIVE_FILE
    try:
        state = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return state if isinstance(state, dict) and isinstance(state.get("waves"), list) else None


def waves_table(root: str | Path) -> ReportTable:
    """One row per claim, one column per wave (its sequential verdict then), and the run's
    stop in the records and notes; empty for a run with fixed seeds."""
    state = read_waves(root)
    waves = state["waves"] if state else []
    metrics = [f"wave {w['wave']}" for w in waves]
    table = ReportTable(
        key="adaptive",
        title="Sequential run: each claim's verdict after every wave",
        caption=(
            "A sequential run ([adaptive]) read its claims after every wave of seeds with "
            "their anytime-valid confidence sequences (claims.sequential) and gave the next "
            "seeds to the undecided ones (tourney.adaptive); a decided claim asked for no "
            "more. Each cell: the claim's sequential verdict as read after that wave."
        ),
        groups=[GROUP] if waves else [],
        metrics={GROUP: metrics} if waves else {},
    )
    table.lap_metrics = set()
    if not state or not waves:
        return table
    claims = list(dict.fromkeys(c["claim"] for w in waves for c in w["claims"]))
    for claim in claims:
        row = table.add_row(claim, "entrant", claim)
        for wave, metric in zip(waves, metrics, strict=True):
            verdict = next((c["verdict"] for c in wave["claims"] if c["claim"] == claim), DASH)
            row["text"][(GROUP, metric)] = verdict
    stopped = state.get("stopped") or {}
    last = waves[-1]
    design = state.get("design") or {}
    table.notes.append(
        f"design: min_seeds {design.get('min_seeds')}, max_seeds {design.get('max_seeds')}, "
        f"wave_seeds {design.get('wave_seeds')}, budget "
        + (f"{design['budget_cpu_h']:g} CPU-h" if design.get("budget_cpu_h") else "none")
    )
    table.notes.append(
        f"stopped: {stopped.get('reason', 'not yet (the run goes on)')}; "
        f"{last.get('spent_cpu_s', 0.0) / 3600.0:.3f} CPU-h spent by the last "
        "wave's reading"
    )
    table.notes.append("seeds: " + ", ".join(f"{k} {v}" for k, v in last["seeds"].items()))
    table.records.append(
        {
            "stopped": stopped.get("reason"),
            "waves": len(waves),
            "design": design,
            "seeds": last["seeds"],
            "claims": stopped.get("claims") or {c["claim"]: c["verdict"] for c in last["claims"]},
        }
    )
    return table
