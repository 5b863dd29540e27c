"""Where the best laps lose time against the reference limit, sector by sector, beside the bots.

The best/limit goals (oval 1.02, technical 1.05; docs/agents.md) are missed by laps that are
1.04-1.08 x the limit; a ratio does not say where the time goes. This reads each run's best clean
test lap (``traces/<track>.parquet`` in the job folders a benchmark wrote with ``--out DIR``),
drives the follower on the lines named by ``--bots`` (its best clean lap of three), and lays
every lap against the QSS profile of ``--profile`` (default the min-curvature line, whose QSS lap
is the track's reference limit), per sector of the track's own segment list
(``lines.lap_loss``): time in the sector, loss, minimum and exit speed against the profile's.

    .venv/bin/python benchmarks/lap_loss.py DIR/WIN1-tuned/seed-* [--bots centre,mincurv]
        [--profile mincurv] [--plot FILE.png]

The table goes to stderr; the last line on stdout is one JSON object.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from formula_tourney.bots.baselines import bot_report  # noqa: E402
from formula_tourney.bots.line_offsets import reference_offsets  # noqa: E402
from formula_tourney.lines.lap_loss import LapLoss, lap_loss, track_sectors  # noqa: E402
from formula_tourney.lines.registry import check_kind  # noqa: E402
from formula_tourney.lines.speed_profile import speed_profile  # noqa: E402
from formula_tourney.report.plots import one_lap, save_figure  # noqa: E402
from formula_tourney.results.folder import JobFolder  # noqa: E402
from formula_tourney.sim.car_params import CarParams  # noqa: E402
from formula_tourney.sim.catalog import load_track  # noqa: E402
from formula_tourney.sim.track import Track  # noqa: E402
from formula_tourney.training.run_spec import RunSpec  # noqa: E402


def run_lap(job: str) -> tuple[str, str, dict[str, np.ndarray] | None, float, CarParams]:
    """A job folder's key track, its label, the trace and time of its best clean test lap, and
    the car it drove (the bots and the profile must be of that car to be its yardstick)."""
    folder = JobFolder(job)
    spec = RunSpec.from_json(folder.config(), job)
    track = spec.key_track
    car = spec.env.car_params()
    label = f"{Path(job).resolve().parent.name}/{Path(job).resolve().name}"
    frame = folder.trace(track)
    if frame is None or frame.empty:
        return track, label, None, math.nan, car
    trace = {c: frame[c].to_numpy(float) for c in frame.columns}
    return track, label, trace, float(trace["time_s"].max()), car


def bot_lap(track: Track, line: str, car: CarParams,
            laps: int = 3) -> tuple[dict[str, np.ndarray] | None, float]:  # fmt: skip
    """The follower's best clean lap on ``line`` (a flying lap: the first starts from rest)."""
    report = bot_report(track, line, laps=laps, car=car)
    best = float(report["best_lap_s"])
    if not math.isfinite(best):
        return None, math.nan
    frame = one_lap(pd.DataFrame(report["_trace"]), report["laps"], report["lap_damage"])
    return {c: frame[c].to_numpy(float) for c in ("time_s", "s_m", "speed_kmh")}, best


def print_table(track: Track, limit_s: float, drivers: list[dict[str, Any]]) -> None:
    """Sectors down, drivers across: each driver's loss (s) and minimum speed driven / profile's
    (km/h) in the sector; the last row is the lap's gap and time."""
    width = max(18, *(len(d["name"]) for d in drivers)) + 2
    print(f"{track.name}: QSS profile {limit_s:.2f} s; per sector the loss against it (s) and "
          "the minimum speed driven / the profile's (km/h)", file=sys.stderr)  # fmt: skip
    print(f"{'sector':<24}{'profile s':>10}" + "".join(f"{d['name']:>{width}}" for d in drivers),
          file=sys.stderr)  # fmt: skip
    first = drivers[0]["loss"]
    for k, sec in enumerate(first.sectors):
        cells = [d["loss"].sectors[k] for d in drivers]
        row = "".join(f"{c.loss_s:+.3f} {c.min_speed_kmh:.0f}/"
                      f"{c.profile_min_speed_kmh:.0f}".rjust(width) for c in cells)  # fmt: skip
        print(f"{sec.name:<24}{sec.profile_s:>10.2f}{row}", file=sys.stderr)
    for kind in first.loss_by_kind():
        profile_s = sum(sec.profile_s for sec in first.sectors if sec.kind == kind)
        row = "".join(f"{d['loss'].loss_by_kind()[kind]:+.3f}".rjust(width)
                      for d in drivers)  # fmt: skip
        print(f"{'all ' + kind + 's':<24}{profile_s:>10.2f}{row}", file=sys.stderr)
    row = "".join(f"{d['lap_s'] - limit_s:+.3f} = {d['lap_s']:.2f} s".rjust(width) for d in drivers)
    print(f"{'lap':<24}{limit_s:>10.2f}{row}", file=sys.stderr)


def plot(track: Track, profile: Any, drivers: list[dict[str, Any]], out: Path) -> list[Path]:
    """Speed along the track and the running time lost against the profile, one line per lap."""
    import matplotlib  # only a run with --plot pays for matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 5.6), sharex=True)
    top.plot(track.s_m, profile.speed_kmh, color="black", lw=1.2, label="QSS profile")
    for d in drivers:
        s = np.mod(d["trace"]["s_m"], track.length_m)
        order = np.argsort(s)
        top.plot(s[order], d["trace"]["speed_kmh"][order], lw=0.9,
                 label=f"{d['name']} ({d['lap_s']:.2f} s)")  # fmt: skip
        loss: LapLoss = d["loss"]
        bottom.plot(loss.stations_m, loss.loss_s, lw=0.9)
    for sec in drivers[0]["loss"].sectors:
        for ax in (top, bottom):
            ax.axvline(sec.s_start_m, color="grey", lw=0.4, alpha=0.5)
    top.set_ylabel("speed (km/h)")
    top.legend(fontsize=7, loc="lower right")
    bottom.set_ylabel("time lost to the profile (s)")
    bottom.set_xlabel("distance along the centre line (m); grey: the track's segments")
    top.set_title(f"{track.name}: best laps against the QSS profile ({profile.lap_time_s:.2f} s)")
    fig.tight_layout()
    return save_figure(fig, out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("jobs", nargs="*", help="job folders (time_to_competence.py --out DIR)")
    ap.add_argument("--track", default=None,
                    help="track (default: the jobs' key track; without jobs: oval, bots only)")
    ap.add_argument("--bots", default="mincurv", help="follower lines, comma-separated ('' none)")
    ap.add_argument("--profile", default="mincurv", help="line whose QSS profile is the yardstick")
    ap.add_argument("--bin-m", type=float, default=100.0,
                    help="sector length on tracks without a segment list")
    ap.add_argument("--plot", default=None, metavar="FILE", help="figure: FILE.png and FILE.pdf")
    args = ap.parse_args()  # fmt: skip
    laps = [run_lap(job) for job in args.jobs]
    names = {t for t, _, _, _, _ in laps} | ({args.track} if args.track else set())
    if not names:
        names = {"oval"}  # `make bench` runs it bare: the followers against the limit
    if len(names) != 1:
        sys.exit(f"lap_loss: give jobs of one track, or --track (got {sorted(names)})")
    cars = {car.fingerprint(): car for *_, car in laps} or {"default": CarParams()}
    if len(cars) != 1:
        sys.exit("lap_loss: give jobs of one car (their env's car settings differ)")
    car = next(iter(cars.values()))
    track = load_track(names.pop())
    profile = speed_profile(track, reference_offsets(track, check_kind(args.profile), car), car)
    sectors = track_sectors(track, args.bin_m)
    entries = [(label, trace, lap) for _, label, trace, lap, _ in laps]
    for line in [b for b in args.bots.split(",") if b]:
        trace, lap = bot_lap(track, check_kind(line), car)
        entries.append((f"follower {line}", trace, lap))
    drivers: list[dict[str, Any]] = []
    for name, trace, lap in entries:
        if trace is None:
            print(f"{name}: no clean lap, left out", file=sys.stderr)
            continue
        drivers.append({"name": name, "lap_s": lap, "trace": trace,
                        "loss": lap_loss(trace, lap, track, profile, sectors)})  # fmt: skip
    if not drivers:
        sys.exit("lap_loss: no clean lap to read")
    print_table(track, profile.lap_time_s, drivers)
    result: dict[str, Any] = {
        "benchmark": "lap_loss", "track": track.name, "profile": args.profile,
        "profile_lap_s": round(profile.lap_time_s, 3),
        "drivers": [{"name": d["name"], "lap_s": round(d["lap_s"], 3),
                     "lap_over_profile": round(d["lap_s"] / profile.lap_time_s, 4),
                     "loss_by_kind_s": {k: round(v, 3)
                                        for k, v in d["loss"].loss_by_kind().items()},
                     "sectors": [{k: (round(v, 3) if isinstance(v, float) else v)
                                  for k, v in s.as_dict().items()} for s in d["loss"].sectors]}
                    for d in drivers],
    }  # fmt: skip
    if args.plot:
        result["plot"] = [str(p) for p in plot(track, profile, drivers, Path(args.plot))]
    print(json.dumps(result))


if __name__ == "__main__":
    main()
