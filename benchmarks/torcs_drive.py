"""The follower on every track of torcs-data, in three dimensions: every one must drive clean.

For each ``<category>/<name>/<name>.xml`` under the torcs-data tracks folder: import it (heights,
banking and surfaces included), compute its reference limit (the QSS lap on the min-curvature
line, with slope, banking, crests and the surface's friction), and drive the follower bot two
laps of that line in the simulator. Prints a Markdown table (the one in docs/tracks.md): length,
z range, max banking, reference limit, the follower's best clean lap and its gap to the limit,
and whether the drive was clean (both laps, no damage) or why not (where the follower cannot
hold the min-curvature line it drives the centre line, and the table says so); the last line
is one JSON object. Nothing is written but the line cache. Skips (exit 0) when the folder is absent:
torcs-data is not a dependency and never enters the test suite.

    .venv/bin/python benchmarks/torcs_drive.py [--tracks DIR] [--only NAME ...] [--laps 2]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from formula_tourney.bots.follower import drive
from formula_tourney.errors import UserInputError
from formula_tourney.lines.limit import reference_limit_s
from formula_tourney.lines.registry import reference_offsets
from formula_tourney.sim.torcs import load_torcs_track

DEFAULT_DIR = Path("/usr/share/games/torcs/tracks")


def one_track(path: Path, laps: int) -> dict:
    """Import, limit and follower drive of one TORCS track file."""
    row: dict = {"name": path.stem, "category": path.parent.parent.name}
    t0 = time.process_time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            track = load_torcs_track(path)
        except UserInputError as err:
            row.update(imported=False, clean=False, reason=f"import: {err}")
            return row
    row["warnings"] = len(caught)
    row.update(imported=True, length_m=track.length_m, z_range_m=float(np.ptp(track.z_m)),
               max_banking_deg=float(np.degrees(np.max(np.abs(track.banking_rad)))),
               min_friction=float(np.min(track.friction_road)))
    row["limit_s"] = reference_limit_s(track)
    row["line"] = "mincurv"
    result = drive(track, reference_offsets(track, "mincurv"), laps=laps)
    if not _clean(result):
        # A line the follower cannot hold is a fact about the follower, not the track: say
        # why, and drive the centre line (the widest margin to both edges) instead.
        row["mincurv_failure"] = _why(result)
        row["line"] = "centre"
        result = drive(track, reference_offsets(track, "centre"), laps=laps)
    row["lap_times_s"] = result["lap_times_s"]
    row["best_lap_s"] = result["best_lap_s"]
    row["damage"] = result["damage"]
    row["clean"] = _clean(result)
    if not row["clean"]:
        row["reason"] = _why(result)
    if math.isfinite(row["best_lap_s"]):
        row["gap_pct"] = 100.0 * (row["best_lap_s"] / row["limit_s"] - 1.0)
    row["cpu_s"] = time.process_time() - t0
    return row


def _clean(result: dict) -> bool:
    return bool(result["finished"] and result["damage"] == 0.0)


def _why(result: dict) -> str:
    end_s = result["trace"]["s_m"][-1] if result["trace"]["s_m"] else math.nan
    return (f"{result['termination'] or 'damage'} at s = {end_s:.0f} m after "
            f"{len(result['lap_times_s'])} laps, damage {result['damage']:.0f}")


def table(rows: list[dict]) -> list[str]:
    out = ["| Track | Length (m) | z range (m) | Max banking (deg) | Reference limit (s) "
           "| Follower best lap (s) | Gap | Clean |",
           "|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        if not r["imported"]:
            out.append(f"| {r['category']}/{r['name']} | - | - | - | - | - | - | no: "
                       f"{r['reason']} |")
            continue
        best = r["best_lap_s"]
        lap = f"{best:.2f}" if math.isfinite(best) else "-"
        gap = f"{r['gap_pct']:+.1f} %" if "gap_pct" in r else "-"
        clean = "yes" if r["clean"] else f"no: {r['reason']}"
        if r["line"] != "mincurv":
            clean += f" (centre line; min-curvature: {r['mincurv_failure']})"
        out.append(f"| {r['category']}/{r['name']} | {r['length_m']:.1f} | "
                   f"{r['z_range_m']:.1f} | {r['max_banking_deg']:.1f} | {r['limit_s']:.2f} | "
                   f"{lap} | {gap} | {clean} |")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tracks", type=Path, default=DEFAULT_DIR)
    parser.add_argument("--only", nargs="*", default=None, help="track names (file stems)")
    parser.add_argument("--laps", type=int, default=2)
    args = parser.parse_args()
    files = sorted(args.tracks.glob("*/*/*.xml"))
    if args.only:
        files = [f for f in files if f.stem in set(args.only)]
    if not files:
        print(f"skipped: no TORCS tracks under {args.tracks} (apt-get install torcs-data)")
        return 0
    rows = []
    for path in files:
        rows.append(one_track(path, args.laps))
        r = rows[-1]
        print(f"# {r['name']}: clean={r['clean']} best={r.get('best_lap_s')} "
              f"limit={r.get('limit_s')} cpu={r.get('cpu_s', 0):.0f}s", file=sys.stderr,
              flush=True)
    print("\n".join(table(rows)))
    gaps = [r["gap_pct"] for r in rows if r["clean"] and "gap_pct" in r]
    summary = {
        "tracks": len(rows),
        "imported": sum(r["imported"] for r in rows),
        "clean": sum(r["clean"] for r in rows),
        "mean_gap_pct": float(np.mean(gaps)) if gaps else None,
        "max_gap_pct": float(np.max(gaps)) if gaps else None,
        "not_clean": {r["name"]: r.get("reason") for r in rows if not r["clean"]},
        "rows": [{k: v for k, v in r.items() if k != "lap_times_s"} for r in rows],
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
