"""How much of a lap bends tight: generated kinds against the tracks a general driver is tested on.

``sim.generate.tight_corner_share`` (the centre line's curvature averaged over ~10 m, the share
under 40 m of radius) for seeds 0..N-1 of each generated kind and for the named tracks; the
figures docs/tracks.md gives for ``gen-short`` come from here.

    .venv/bin/python benchmarks/track_tightness.py [--seeds 150] [--tracks technical,aalborg]

Named tracks that are not on this machine (aalborg is imported from torcs-data) are skipped.
The last line is one JSON object.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402

import numpy as np  # noqa: E402

from formula_tourney.errors import UserInputError  # noqa: E402
from formula_tourney.sim.catalog import load_track  # noqa: E402
from formula_tourney.sim.generate import (  # noqa: E402
    GENERATED_KINDS,
    generated_track,
    tight_corner_share,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=150, help="seeds 0..N-1 of each kind")
    ap.add_argument("--tracks", default="oval,technical,flowing,michigan,aalborg,forza")
    args = ap.parse_args()
    kinds = {}
    for prefix in GENERATED_KINDS:
        shares = np.array([tight_corner_share(generated_track(prefix, s))
                           for s in range(args.seeds)])  # fmt: skip
        kinds[prefix] = {"median": round(float(np.median(shares)), 4),
                         "p90": round(float(np.percentile(shares, 90)), 4),
                         "max": round(float(shares.max()), 4)}  # fmt: skip
        print(f"{prefix}: {kinds[prefix]}")
    named = {}
    for name in args.tracks.split(","):
        try:
            named[name] = round(tight_corner_share(load_track(name)), 4)
        except UserInputError:
            continue
        print(f"{name}: {named[name]}")
    print(json.dumps({"benchmark": "track_tightness", "seeds": args.seeds, "kinds": kinds,
                      "tracks": named}))


if __name__ == "__main__":
    main()
