"""How much of the best bot's gap to the reference limit is the gearbox's, per track.

The reference limit (a QSS lap of the min-curvature line) takes the largest drive force over all
gears at every speed: an ideal gearbox. The simulated car's automatic gearbox shifts up at
``upshift_rpm`` and down only below ``downshift_rpm`` (4 000 by default), so after a straight it
stays in top gear through a long fast arc (the oval's R250 arcs: 6th at ~6 200-6 600 rpm, 3 600 N
against the 4 245 N of 5th). This drives the follower on each line for each ``downshift_rpm``
given, beside the limit (which does not depend on it), so the share of the gap that no driver can
recover in the default car shows as a lap time.

    .venv/bin/python benchmarks/gearbox_limit.py [--tracks oval,technical]
        [--downshift-rpm 4000,7000] [--lines centre,mincurv] [--laps 3]

The table goes to stderr; the last line on stdout is one JSON object.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
from typing import Any  # noqa: E402

from formula_tourney.bots.baselines import bot_report  # noqa: E402
from formula_tourney.lines.limit import reference_limit_s  # noqa: E402
from formula_tourney.lines.registry import check_kind  # noqa: E402
from formula_tourney.sim.car_params import CarParams  # noqa: E402
from formula_tourney.sim.catalog import load_track  # noqa: E402

GOALS = {"oval": 1.02, "technical": 1.05}
"""The best lap / limit goals of docs/agents.md, for the best bot's ratio beside them."""


def row(track_name: str, downshift_rpm: float, lines: list[str], laps: int) -> dict[str, Any]:
    """The followers' best clean laps and the limit for one track and one shift point."""
    track = load_track(track_name)
    car = CarParams(downshift_rpm=downshift_rpm)
    limit_s = float(reference_limit_s(track, car))
    out: dict[str, Any] = {"track": track_name, "downshift_rpm": downshift_rpm,
                           "limit_s": round(limit_s, 3)}  # fmt: skip
    for line in lines:
        report = bot_report(track, check_kind(line), laps=laps, car=car)
        best = float(report["best_lap_s"])
        out[line] = {"lap_s": round(best, 3) if math.isfinite(best) else None,
                     "over_limit": round(best / limit_s, 4) if math.isfinite(best) else None,
                     "termination": report["termination"]}  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracks", default="oval,technical")
    ap.add_argument("--downshift-rpm", default="4000,7000",
                    help="comma-separated shift-down points; the first is the baseline")
    ap.add_argument("--lines", default="centre,mincurv", help="follower lines, comma-separated")
    ap.add_argument("--laps", type=int, default=3, help="laps per drive (the best clean counts)")
    args = ap.parse_args()
    try:
        rpms = [float(x) for x in args.downshift_rpm.split(",") if x.strip()]
    except ValueError:
        sys.exit(f"gearbox_limit: --downshift-rpm wants numbers, got {args.downshift_rpm!r}")
    if not rpms:
        sys.exit("gearbox_limit: --downshift-rpm is empty")
    lines = [x for x in args.lines.split(",") if x]
    rows = [row(t, r, lines, args.laps) for t in args.tracks.split(",") if t for r in rpms]
    print(f"{'track':<12}{'downshift rpm':>14}{'limit s':>9}"
          + "".join(f"{line + ' s (x limit)':>24}" for line in lines), file=sys.stderr)
    for r in rows:
        cells = "".join(
            f"{r[line]['lap_s']:.3f} ({r[line]['over_limit']:.4f})".rjust(24)
            if r[line]["lap_s"] is not None else f"no clean lap: {r[line]['termination']}".rjust(24)
            for line in lines)  # fmt: skip
        print(f"{r['track']:<12}{r['downshift_rpm']:>14.0f}{r['limit_s']:>9.3f}{cells}",
              file=sys.stderr)
    gains: dict[str, dict[str, float | None]] = {}
    for r in rows:
        base = next(b for b in rows if b["track"] == r["track"])
        if r is base:
            continue
        key = f"{r['track']}@{r['downshift_rpm']:.0f}"
        gains[key] = {line: (round(base[line]["lap_s"] - r[line]["lap_s"], 3)
                             if base[line]["lap_s"] is not None and r[line]["lap_s"] is not None
                             else None) for line in lines}  # fmt: skip
    print(json.dumps({"benchmark": "gearbox_limit", "rows": rows,
                      "lap_gain_s_against_first_rpm": gains,
                      "goals_best_lap_over_limit": GOALS}))


if __name__ == "__main__":
    main()
