"""The 38 tracks of torcs-data against TORCS' own numbers.

Imports every ``<category>/<name>/<name>.xml`` under the torcs-data tracks folder and prints a
Markdown table (the one in docs/tracks.md): our lap length, TORCS' lap length, the difference,
our closure gap, TORCS' gap, sub-segment counts (ours / TORCS') and whether the track imports.
The last line is one JSON object. Nothing is written. Skips (exit 0) when the folder is absent:
torcs-data is not a dependency (``apt-get install torcs-data`` provides it).

    .venv/bin/python benchmarks/torcs_tracks.py [--tracks /usr/share/games/torcs/tracks]

The reference numbers below were measured once, by hand, with TORCS' own track loader: Debian's
``torcs`` 1.3.7+dfsg-5 (with torcs-data 1.3.7+dfsg-5), running its ``trackgen -c CAT -n NAME``
under ``xvfb-run``; trackgen loads the track with TORCS' track module and prints ``length``
(the sum of the sub-segment lengths, TORCS' lap length), ``nseg`` (sub-segments) and ``Delta
X`` / ``Delta Y`` (start minus end of the main track, i.e. the gap TORCS leaves open). TORCS
computes in 32-bit floats, so its last digits carry float noise (~1e-5 of the length).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from formula_tourney.errors import UserInputError
from formula_tourney.sim import torcs
from formula_tourney.sim.segments import build_lanes, build_track

DEFAULT_DIR = Path("/usr/share/games/torcs/tracks")

# name: (length m, Delta X m, Delta Y m, nseg), as TORCS 1.3.7's trackgen printed them.
TORCS_1_3_7 = {
    "dirt-1": (1072.932617, -0.000397, -0.000427, 210),
    "dirt-2": (1760.941772, 0.000000, 0.000050, 550),
    "dirt-3": (2205.934814, 0.035706, -0.003571, 457),
    "dirt-4": (3260.425049, 0.000610, 0.000671, 565),
    "dirt-5": (1072.932373, 0.000046, -0.000031, 195),
    "dirt-6": (3147.457275, 0.000397, -0.000126, 477),
    "mixed-1": (1014.218140, 0.000000, 0.000015, 230),
    "mixed-2": (1412.897461, 0.000031, 0.000397, 310),
    "a-speedway": (1908.320679, -0.000214, -0.000555, 244),
    "b-speedway": (3999.117432, -0.000305, -0.000305, 410),
    "c-speedway": (3294.398193, 0.002197, 0.002991, 336),
    "d-speedway": (3427.432861, -0.002075, -0.000183, 349),
    "e-speedway": (4103.839844, -0.000366, -0.000183, 420),
    "e-track-5": (1621.731934, 0.000809, 0.000275, 335),
    "f-speedway": (3703.834473, -0.000366, -0.000671, 380),
    "g-speedway": (2977.596436, 0.002014, 0.000977, 306),
    "michigan": (2311.790283, -0.006226, 0.002014, 248),
    "aalborg": (2587.543457, 0.000122, -0.001801, 371),
    "alpine-1": (6355.651367, 0.007202, -0.000427, 1179),
    "alpine-2": (3773.574951, -0.069061, 0.012043, 966),
    "brondehach": (3919.313965, -0.000763, 0.005615, 1048),
    "corkscrew": (3608.446289, 0.011871, 0.004295, 606),
    "e-track-1": (3243.644043, -0.000793, 0.000353, 416),
    "e-track-2": (5380.502441, 0.000061, -0.000080, 1334),
    "e-track-3": (4208.365723, -0.000061, -0.000061, 781),
    "e-track-4": (7041.681641, -0.005493, -0.005188, 709),
    "e-track-6": (4441.289062, 0.003601, -0.005676, 481),
    "eroad": (3260.426025, 0.000793, -0.002724, 402),
    "forza": (5784.097168, -0.143311, 0.037476, 1509),
    "g-track-1": (2057.559326, -0.001160, 0.001106, 301),
    "g-track-2": (3185.832520, 0.002716, 0.050293, 504),
    "g-track-3": (2843.095459, 0.006897, 0.005112, 350),
    "ole-road-1": (6282.809082, -0.003723, 0.000839, 724),
    "ruudskogen": (3274.203125, -0.046692, 0.066956, 788),
    "spring": (22129.765625, -0.011963, -0.002075, 2956),
    "street-1": (3823.050537, 0.006271, 0.067352, 635),
    "wheel-1": (4328.540039, 0.000183, -0.000671, 848),
    "wheel-2": (6205.462891, -0.242432, -0.094727, 1200),
}


def sub_segment_count(path: Path) -> int:
    """Sub-segments TORCS cuts the main track into, by the importer's own rule (its helpers)."""
    root = torcs.parse_xml_safely(path.read_bytes(), str(path))
    main = torcs._section(root, "Main Track")
    segs = torcs._section(main, "Track Segments") or torcs._section(main, "segments")
    step = torcs._num(main, "profil steps length", torcs.LENGTH_UNITS, str(path), 0.0)
    total = 0
    for sec in (c for c in segs if c.tag == "section"):
        where = f"{path}: {sec.get('name')}"
        if torcs._attr(sec, "type").get("val").strip() == "str":
            length = torcs._num(sec, "lg", torcs.LENGTH_UNITS, where)
        else:
            radius = torcs._num(sec, "radius", torcs.LENGTH_UNITS, where)
            end = torcs._num(sec, "end radius", torcs.LENGTH_UNITS, where, radius)
            length = torcs._num(sec, "arc", torcs.ANGLE_UNITS, where) * (radius + end) / 2.0
        total += torcs._sub_segments(sec, length, step, where)
    return total


def one_track(path: Path) -> dict:
    name = path.stem
    row: dict = {"name": name, "category": path.parent.parent.name}
    spec = torcs.read_torcs_spec(path)
    pieces = build_lanes(spec)
    last = pieces[-1]
    end = last.lane.position(last.length_m, 0.0)
    row["length_m"] = sum(p.length_m for p in pieces)
    row["gap_m"] = math.hypot(float(end[0]), float(end[1]))
    row["sub_segments"] = sub_segment_count(path)
    try:
        build_track(spec, str(path))
        row["imported"] = True
    except UserInputError as err:
        row["imported"] = False
        row["refused"] = str(err).split(": ", 1)[-1]
    ref = TORCS_1_3_7.get(name)
    if ref is not None:
        length, dx, dy, nseg = ref
        row["torcs_length_m"] = length
        row["diff_pct"] = 100.0 * (row["length_m"] - length) / length
        row["torcs_gap_m"] = math.hypot(dx, dy)
        # TORCS prints start - end, we have end - start: how far apart the two gap vectors are.
        row["gap_vs_torcs_m"] = math.hypot(float(end[0]) + dx, float(end[1]) + dy)
        row["torcs_sub_segments"] = nseg
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tracks", type=Path, default=DEFAULT_DIR)
    args = parser.parse_args()
    files = sorted(args.tracks.glob("*/*/*.xml"))
    if not files:
        print(f"skipped: no TORCS tracks under {args.tracks} (apt-get install torcs-data)")
        return 0
    rows = [one_track(path) for path in files]
    print("| Track | Ours (m) | TORCS (m) | Diff % | Our gap (m) | TORCS gap (m) "
          "| Sub-segments ours / TORCS | Imported |")
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    for r in rows:
        ref = "torcs_length_m" in r
        print(f"| {r['category']}/{r['name']} | {r['length_m']:.2f} | "
              + (f"{r['torcs_length_m']:.2f} | {r['diff_pct']:+.4f} | " if ref else "- | - | ")
              + f"{r['gap_m']:.3f} | "
              + (f"{r['torcs_gap_m']:.3f} | " if ref else "- | ")
              + f"{r['sub_segments']} / {r.get('torcs_sub_segments', '-')} | "
              + ("yes" if r["imported"] else f"no: {r['refused']}") + " |")
    with_ref = [r for r in rows if "diff_pct" in r]
    summary = {
        "tracks": len(rows),
        "imported": sum(r["imported"] for r in rows),
        "max_abs_diff_pct": max((abs(r["diff_pct"]) for r in with_ref), default=None),
        "max_gap_m": max(r["gap_m"] for r in rows),
        "max_gap_vs_torcs_m": max((r["gap_vs_torcs_m"] for r in with_ref), default=None),
        "sub_segment_mismatches": [r["name"] for r in with_ref
                                   if r["sub_segments"] != r["torcs_sub_segments"]],
        "refused": {r["name"]: r["refused"] for r in rows if not r["imported"]},
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
