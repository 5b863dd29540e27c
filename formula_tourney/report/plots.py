"""The paper's figures (matplotlib Agg, PNG and PDF) from the store's frames and traces.

Each ``plot_*`` function draws one figure from plain frames and returns the files it wrote, so it
can be called on any run's data; ``make_figures`` picks what to draw for a whole tournament
(learning curves per part, generalisation per Table 3 configuration, traces/line/delta for each
Table 1 column's fastest run, and adopted-target ablation pairs). A number a figure prints that a
table also shows (a lap time in a title) is passed in from the table, never recomputed here.
"""

from __future__ import annotations

import io
import math
import re
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.errors import UserInputError
from formula_tourney.lines.kinds import line_label
from formula_tourney.report import stats
from formula_tourney.report.paper_tables import Context, bot_row_label
from formula_tourney.report.table_model import ReportTable
from formula_tourney.results import metrics
from formula_tourney.safeio import atomic_write_bytes
from formula_tourney.sim.catalog import load_track

FORMATS = ("png", "pdf")
DPI = 120
CHARS_PER_INCH = {7: 15.0, 8: 13.0, 9: 11.5, 10: 10.5, 12: 8.5}
"""About how many characters of DejaVu Sans at a font size (pt) fit one inch: the width a title
or legend label is wrapped at so that it stays inside its panel."""
# Paper colours: Figure 4 (generalisation) blue/brown/green per track; Figure 6 green = normal
# end-of-episode target, red = adopted target.
TRACK_COLOURS = ["tab:blue", "tab:brown", "tab:green", "tab:purple", "tab:orange", "tab:cyan"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def subplots(*args: Any, **kwargs: Any) -> tuple[Any, Any]:
    """``plt.subplots`` with matplotlib's constrained layout: panels, their tick labels, axis
    labels, legends and colorbars are placed so that none overlaps another or leaves the canvas
    (``tests/test_report_figures.py`` checks every text of every figure)."""
    return _pyplot().subplots(*args, layout="constrained", **kwargs)


def wrap(text: str, width_in: float, fontsize: int = 10) -> str:
    """``text`` broken into lines that fit ``width_in`` inches at ``fontsize`` pt."""
    per_inch = CHARS_PER_INCH.get(fontsize, 10.5 * 10 / fontsize)
    return "\n".join(textwrap.wrap(str(text), max(int(width_in * per_inch), 12)) or [""])


def slug(text: str) -> str:
    """A file-name-safe form of a label (``part1: oval MOT`` -> ``part1-oval-mot``)."""
    out = re.sub(r"[^A-Za-z0-9]+", "-", str(text)).strip("-").lower()
    return out or "figure"


def figure_title(fig: Any) -> str:
    """The figure's title on one line: its suptitle, else its first panel's title."""
    sup = getattr(fig, "_suptitle", None)
    text = sup.get_text() if sup is not None else ""
    if not text and fig.axes:
        text = fig.axes[0].get_title()
    return " ".join(text.split())


def save_figure(fig: Any, out_base: Path) -> list[Path]:
    """Write ``out_base.png`` and ``out_base.pdf`` atomically and close the figure. Both carry
    the figure's title as their ``Title`` metadata, which the HTML page's caption reads."""
    plt = _pyplot()
    paths = []
    title = figure_title(fig)
    try:
        for fmt in FORMATS:
            buf = io.BytesIO()
            fig.savefig(buf, format=fmt, dpi=DPI, bbox_inches="tight",
                        metadata={"Title": title} if title else None)
            paths.append(atomic_write_bytes(out_base.with_suffix(f".{fmt}"), buf.getvalue()))
    finally:
        plt.close(fig)
    return paths


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average ignoring nans (the paper smooths rewards over 5-20 episodes)."""
    arr = np.asarray(values, dtype=float)
    if window <= 1 or arr.size == 0:
        return arr
    series = pd.Series(arr)
    return series.rolling(window, min_periods=1).mean().to_numpy()


def _seed_matrix(frame: pd.DataFrame, value: str, smooth: int) -> tuple[np.ndarray, np.ndarray]:
    """(episodes, (seeds, episodes) matrix) of one entrant's per-seed curves, each smoothed;
    nan after a seed's last episode (a seed that stopped earlier has no value there)."""
    episodes = np.sort(frame["episode"].dropna().unique())
    rows = []
    for _, grp in frame.groupby("job_id", sort=False):
        series = grp.groupby("episode")[value].mean().reindex(episodes)
        smoothed = np.array(moving_average(series.to_numpy(dtype=float), smooth), dtype=float)
        smoothed[episodes > grp["episode"].max()] = np.nan
        rows.append(smoothed)
    return episodes, np.vstack(rows) if rows else np.empty((0, episodes.size))


def seed_counts(episodes: np.ndarray, matrix: np.ndarray) -> list[tuple[float, int]]:
    """Where the number of seeds with a value changes: (first episode, n) for each stretch."""
    counts = np.isfinite(matrix).sum(axis=0)
    out: list[tuple[float, int]] = []
    for x, n in zip(episodes, counts, strict=True):
        if not out or out[-1][1] != int(n):
            out.append((float(x), int(n)))
    return out


def n_label(changes: list[tuple[float, int]]) -> str:
    """``n=2`` or ``n=2, n=1 from ep 190``: the seeds a mean is over, where that changes."""
    if not changes:
        return "n=0"
    parts = [f"n={changes[0][1]}"]
    parts += [f"n={n} from ep {x:g}" for x, n in changes[1:]]
    return ", ".join(parts)


def _band_plot(ax: Any, x: np.ndarray, matrix: np.ndarray, label: str, colour: Any) -> None:
    """Mean over seeds with its 95% band; the legend gives n, and where it changes. Where fewer
    seeds than the most have a value (one stopped earlier) the mean is dashed: a jump there is
    the stopped seed leaving the mean, not the others' learning."""
    mean, low, high = stats.band(matrix)
    label = wrap(f"{label} ({n_label(seed_counts(x, matrix))})", 6.5, 8)
    counts = np.isfinite(matrix).sum(axis=0)
    full = counts == counts.max() if counts.size else counts.astype(bool)
    ax.plot(x, np.where(full, mean, np.nan), color=colour, label=label, lw=1.4)
    if not full.all():
        # dashed over the stretches with fewer seeds, joined to the solid line at each edge
        short = ~full
        edge = short.copy()
        edge[1:] |= short[:-1]
        edge[:-1] |= short[1:]
        ax.plot(x, np.where(edge, mean, np.nan), color=colour, lw=1.2, ls="--")
    if matrix.shape[0] > 1:
        ax.fill_between(x, low, high, color=colour, alpha=0.2, lw=0)


def _mark_stops(ax: Any, frame: pd.DataFrame, x: np.ndarray, matrix: np.ndarray,
                colour: Any) -> bool:
    """An ``x`` at the last episode of every seed that stopped before the others; whether any
    did."""
    last = float(x[-1]) if x.size else math.nan
    stopped = False
    for row, (_, grp) in zip(matrix, frame.groupby("job_id", sort=False), strict=True):
        end = float(grp["episode"].max())
        if end < last:
            k = int(np.searchsorted(x, end))
            ax.plot([end], [row[k]], marker="x", ms=8, mew=2, color=colour, ls="none")
            stopped = True
    return stopped


def best_laps_s(models: pd.DataFrame) -> dict[str, float]:
    """Each entrant's best clean lap over its runs' models: the tables' bLT, from
    ``results.metrics`` (``run_table`` then ``blt_alt``), not recomputed here."""
    out: dict[str, float] = {}
    for entrant, grp in models.groupby("entrant", sort=False):
        runs = metrics.run_table(grp)
        out[str(entrant)] = metrics.blt_alt(runs["run_best_s"].to_numpy(dtype=float))[0]
    return out


def plot_learning_curves(episodes: pd.DataFrame, test_laps: pd.DataFrame, title: str,
                         out_base: Path, smooth: int = 20) -> list[Path]:
    """Training reward (moving average; mean and 95% band over seeds) and every clean test lap
    vs episode, one colour per entrant.

    ``test_laps`` holds model rows (``results.metrics.model_table``: job_id, episode, entrant,
    clean_lap_s). Each seed's clean tests are markers joined by a thin line, so an isolated
    clean test shows; a star marks the entrant's best lap, the tables' bLT (``best_laps_s``).
    A seed that stopped before the others ends in an ``x``, and the legend gives n where it
    changes.
    """
    plt = _pyplot()
    fig, (ax_r, ax_l) = subplots(2, 1, figsize=(8, 7.5), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    entrants = list(dict.fromkeys([*episodes.get("entrant", pd.Series(dtype=str)),
                                   *test_laps.get("entrant", pd.Series(dtype=str))]))
    best = best_laps_s(test_laps) if not test_laps.empty else {}
    stopped = False
    for k, entrant in enumerate(entrants):
        colour = colours[k % len(colours)]
        ep = episodes.loc[episodes["entrant"] == entrant]
        if not ep.empty:
            x, m = _seed_matrix(ep, "reward", smooth)
            _band_plot(ax_r, x, m, entrant, colour)
            stopped |= _mark_stops(ax_r, ep, x, m, colour)
        tl = test_laps.loc[test_laps["entrant"] == entrant]
        clean = tl.loc[tl["clean_lap_s"].notna()]
        for _, grp in clean.groupby("job_id", sort=False):
            grp = grp.groupby("episode")["clean_lap_s"].min()
            ax_l.plot(grp.index, grp.to_numpy(dtype=float), color=colour, lw=0.7, alpha=0.6,
                      marker="o", ms=3.5)
        lap_s = best.get(str(entrant), math.nan)
        if math.isfinite(lap_s):
            at = clean.loc[clean["clean_lap_s"] == lap_s, "episode"].min()
            runs = tl["job_id"].nunique()
            ax_l.plot([at], [lap_s], marker="*", ms=13, color=colour, mec="black", ls="none",
                      label=wrap(f"{entrant}: bLT {lap_s:.2f} s (n={runs})", 6.5, 8))
    if stopped:
        ax_r.plot([], [], marker="x", color="0.3", ls="none", label="a seed's last episode")
    if best:
        ax_l.plot([], [], marker="o", ms=3.5, color="0.3", lw=0.7,
                  label="clean test of one seed")
    ax_r.set_ylabel(f"training reward (MA {smooth})")
    ax_l.set_ylabel("clean test lap (s)")
    ax_l.set_xlabel("training episode")
    ax_r.set_title(wrap(title, 7.5, 12))
    for ax in (ax_r, ax_l):
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    return save_figure(fig, out_base)


def plot_generalisation(models: pd.DataFrame, tracks: list[str], title: str, out_base: Path,
                        general: dict[str, Any] | None = None) -> list[Path]:
    """Lap time on each track vs training episode for every run of one configuration (paper,
    Figure 4): one panel per track, the general model's episode as a vertical red line."""
    n = max(len(tracks), 1)
    fig, axes = subplots(n, 1, figsize=(8, 2.2 * n + 1.2), sharex=True, squeeze=False)
    for k, track in enumerate(tracks):
        ax = axes[k][0]
        colour = TRACK_COLOURS[k % len(TRACK_COLOURS)]
        on_track = models.loc[models["track"] == track]
        for job_id, grp in on_track.groupby("job_id", sort=False):
            grp = grp.sort_values("episode")
            ax.plot(grp["episode"], grp["clean_lap_s"], marker="o", ms=3, lw=1, color=colour,
                    alpha=0.8, label=str(job_id).rsplit("/", 1)[-1])
        if general is not None:
            ax.axvline(general["episode"], color="red", lw=1.5)
        ax.set_ylabel(f"{track}\nlap (s)")
        ax.grid(alpha=0.3)
        if on_track["clean_lap_s"].isna().all():
            ax.text(0.5, 0.5, "DNF: no clean lap", transform=ax.transAxes, ha="center")
    axes[0][0].set_title(wrap(title + ("" if general is None else
                                       f"  (red: general model, {general['job_id']})"), 7.5, 12))
    axes[-1][0].set_xlabel("training episode")
    return save_figure(fig, out_base)


def plot_action_trace(trace: pd.DataFrame, title: str, out_base: Path) -> list[Path]:
    """Steer, throttle, brake and speed against distance for one lap (paper, Figure 5)."""
    fig, axes = subplots(4, 1, figsize=(9, 7), sharex=True)
    d = trace["distance_m"].to_numpy(dtype=float)
    d = d - d[0]
    for ax, col, colour, label in zip(
        axes, ("steer", "throttle", "brake", "speed_kmh"),
        ("tab:blue", "tab:green", "tab:red", "black"),
        ("steer (+ left)", "throttle", "brake", "speed (km/h)"), strict=True,
    ):
        ax.plot(d, trace[col].to_numpy(dtype=float), color=colour, lw=1)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-1.05, 1.05)
    axes[1].set_ylim(-0.05, 1.05)
    axes[2].set_ylim(-0.05, 1.05)
    axes[0].set_title(wrap(title, 8.5, 12))
    axes[-1].set_xlabel("distance (m)")
    return save_figure(fig, out_base)


def track_edges(track: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Left and right edge polylines of a ``sim.track.Track`` (closed)."""
    s = np.append(track.s_m, track.s_m[:1])
    left = np.append(track.width_left_m, track.width_left_m[:1])
    right = np.append(track.width_right_m, track.width_right_m[:1])
    xl, yl, _ = track.pose_at(s, left)
    xr, yr, _ = track.pose_at(s, -right)
    return xl, yl, xr, yr


def plot_racing_line(traces: dict[str, pd.DataFrame], title: str, out_base: Path,
                     track: Any = None,
                     lap_times_s: dict[str, float] | None = None) -> list[Path]:
    """Each driver's path on the track map coloured by speed, side by side on one colour scale,
    so that where a bot and an entrant brake and which line they take can be compared.

    ``lap_times_s`` (label -> s) is printed in each panel's title: the lap time the tables show
    for that driver, not one re-measured from the trace (whose samples start up to a control
    step after the line).
    """
    n = max(len(traces), 1)
    fig, axes = subplots(1, n, figsize=(5.2 * n, 5.2), squeeze=False)
    speeds = [t["speed_kmh"].to_numpy(dtype=float) for t in traces.values()]
    vmin = min((float(np.nanmin(s)) for s in speeds if s.size), default=0.0)
    vmax = max((float(np.nanmax(s)) for s in speeds if s.size), default=1.0)
    mappable = None
    for ax, (label, trace) in zip(axes[0], traces.items(), strict=False):
        if track is not None:
            xl, yl, xr, yr = track_edges(track)
            ax.plot(xl, yl, color="0.6", lw=0.8)
            ax.plot(xr, yr, color="0.6", lw=0.8)
        mappable = ax.scatter(trace["x_m"], trace["y_m"], c=trace["speed_kmh"], s=3,
                              cmap="viridis", vmin=vmin, vmax=vmax)
        lap = (lap_times_s or {}).get(label, math.nan)
        head = f"{label}: {lap:.2f} s" if math.isfinite(lap) else label
        ax.set_title(wrap(head, 4.0, 9), fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    if mappable is not None:
        fig.colorbar(mappable, ax=axes[0].tolist(), label="speed (km/h)", shrink=0.8)
    fig.suptitle(wrap(title, 5.0 * n, 12))
    return save_figure(fig, out_base)


def delta_time(trace_a: pd.DataFrame, trace_b: pd.DataFrame,
               points: int = 500) -> tuple[np.ndarray, np.ndarray]:
    """(distance, t_a(d) - t_b(d)) on a common distance grid: > 0 where A is behind B."""
    da = trace_a["distance_m"].to_numpy(dtype=float) - float(trace_a["distance_m"].iloc[0])
    db = trace_b["distance_m"].to_numpy(dtype=float) - float(trace_b["distance_m"].iloc[0])
    ta = trace_a["time_s"].to_numpy(dtype=float) - float(trace_a["time_s"].iloc[0])
    tb = trace_b["time_s"].to_numpy(dtype=float) - float(trace_b["time_s"].iloc[0])
    end = min(da[-1], db[-1])
    grid = np.linspace(0.0, end, points)
    return grid, np.interp(grid, da, ta) - np.interp(grid, db, tb)


def plot_lap_delta(trace_a: pd.DataFrame, trace_b: pd.DataFrame, label_a: str, label_b: str,
                   title: str, out_base: Path) -> list[Path]:
    """Lap against lap: both speeds against distance, and the running time difference A - B
    (> 0 where A is behind). The names stand in the legend as "A: ..." and "B: ...", so the
    difference's axis label stays short however long the entrants' names are."""
    fig, (ax_v, ax_d) = subplots(2, 1, figsize=(9, 6), sharex=True,
                                 gridspec_kw={"height_ratios": [2, 1]})
    for trace, label, colour in ((trace_a, f"A: {label_a}", "tab:red"),
                                 (trace_b, f"B: {label_b}", "tab:blue")):
        d = trace["distance_m"].to_numpy(dtype=float)
        ax_v.plot(d - d[0], trace["speed_kmh"], color=colour, lw=1, label=wrap(label, 7.0, 8))
    grid, delta = delta_time(trace_a, trace_b)
    ax_d.plot(grid, delta, color="black", lw=1)
    ax_d.axhline(0.0, color="0.5", lw=0.8)
    ax_d.fill_between(grid, delta, 0.0, where=delta > 0, color="tab:blue", alpha=0.2)
    ax_d.fill_between(grid, delta, 0.0, where=delta < 0, color="tab:red", alpha=0.2)
    ax_v.set_ylabel("speed (km/h)")
    ax_d.set_ylabel("A \u2212 B (s)")
    ax_d.set_xlabel("distance (m)")
    ax_v.legend(fontsize=8)
    ax_v.set_title(wrap(title, 8.5, 12))
    for ax in (ax_v, ax_d):
        ax.grid(alpha=0.3)
    return save_figure(fig, out_base)


def plot_ablation(episodes: pd.DataFrame, labels: dict[str, str], title: str, out_base: Path,
                  smooth: int = 5) -> list[Path]:
    """Training reward of an ablation pair (paper, Figure 6: normal end-of-episode target in
    green, adopted target in red), mean over seeds with a 95% band, moving average ``smooth``.

    ``labels`` maps entrant -> legend label, in the order (off, on).
    """
    fig, ax = subplots(figsize=(8, 4.5))
    colours = ["tab:green", "tab:red", "tab:blue", "tab:orange"]
    for k, (entrant, label) in enumerate(labels.items()):
        ep = episodes.loc[episodes["entrant"] == entrant]
        if ep.empty:
            continue
        x, m = _seed_matrix(ep, "reward", smooth)
        _band_plot(ax, x, m, label, colours[k % len(colours)])
        _mark_stops(ax, ep, x, m, colours[k % len(colours)])
    ax.set_xlabel("training episode")
    ax.set_ylabel(f"training reward (MA {smooth})")
    ax.set_title(wrap(title, 7.5, 12))
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    return save_figure(fig, out_base)


# --------------------------------------------------------------------------------------------
# choosing figures for a tournament


def ablation_pairs(data: Any) -> list[dict[str, Any]]:
    """Entrant pairs of one part that differ only in one boolean setting (e.g. the adopted
    target flag): same variant, line, LAC and train tracks, and agent and env settings equal but
    for that one. Read from the jobs' run specs (config.json)."""
    pairs: list[dict[str, Any]] = []
    jobs = data.jobs
    if jobs.empty:
        return pairs
    per_entrant: dict[tuple[str, str], dict[str, Any]] = {}
    for _, job in jobs.iterrows():
        cfg = data.configs.get(str(job["job_id"]))
        if cfg is None:
            continue
        key = (str(job["part"]), str(job["entrant"]))
        per_entrant.setdefault(key, {
            "variant": job["variant"], "reference": job["reference"], "lac": bool(job["lac"]),
            "train": tuple(job["train_tracks"]),
            "settings": {**(cfg.get("env") or {}), **(cfg.get("agent") or {})},
        })
    keys = list(per_entrant)
    for i, ka in enumerate(keys):
        for kb in keys[i + 1:]:
            if ka[0] != kb[0]:
                continue
            a, b = per_entrant[ka], per_entrant[kb]
            if any(a[f] != b[f] for f in ("variant", "reference", "lac", "train")):
                continue
            names = set(a["settings"]) | set(b["settings"])
            diff = [n for n in names if a["settings"].get(n) != b["settings"].get(n)]
            if len(diff) != 1:
                continue
            flag = diff[0]
            va, vb = a["settings"].get(flag), b["settings"].get(flag)
            if not all(isinstance(v, bool) or v is None for v in (va, vb)):
                continue
            # off first (green), on second (red), as in the paper's figure
            off, on = (ka[1], kb[1]) if not va else (kb[1], ka[1])
            pairs.append({"part": ka[0], "flag": flag, "off": off, "on": on})
    return pairs


def _load_track(name: str) -> Any:
    """The track's geometry for map backgrounds, or None where it cannot be loaded here (a user
    track of another machine): the map is still drawn from the traces' x, y."""
    try:
        return load_track(name)
    except (UserInputError, OSError, ValueError):
        return None


def one_lap(trace: pd.DataFrame, lap_times_s: list[float] | None = None,
            lap_damage: list[float] | None = None) -> pd.DataFrame:
    """The fastest complete lap of a multi-lap trace (the follower's drive has a ``lap`` column
    counting start-line crossings), time and distance rebased to 0; other traces unchanged.

    The rows' own times only time a lap to one control step; given the drive's exact
    ``lap_times_s`` (lap k's rows carry ``lap == k``) the fastest is chosen by them, and laps
    with ``lap_damage`` > 0 are not candidates (a lap that cut a corner is not a clean lap).
    A trace without ``time_s`` gets one integrated from distance and speed.
    """
    frame = trace.reset_index(drop=True)
    if "time_s" not in frame.columns:
        d = frame["distance_m"].to_numpy(dtype=float)
        v = np.maximum(frame["speed_kmh"].to_numpy(dtype=float) / 3.6, 0.1)
        dt = np.diff(d, prepend=d[0]) * 2.0 / (v + np.roll(v, 1))
        dt[0] = 0.0
        frame["time_s"] = np.cumsum(dt)
    if "lap" in frame.columns:
        laps = frame["lap"].to_numpy()
        complete = [int(k) for k in np.unique(laps) if k >= 1 and (laps > k).any()]
        if lap_times_s is not None:
            damage = list(lap_damage) if lap_damage is not None else [0.0] * len(lap_times_s)
            complete = [k for k in complete if k <= len(lap_times_s) and damage[k - 1] <= 0.0]

        def duration(k: int) -> float:
            if lap_times_s is not None:
                return float(lap_times_s[k - 1])
            rows = frame.loc[laps == k, "time_s"]
            return float(rows.iloc[-1] - rows.iloc[0])

        if complete:
            best = min(complete, key=duration)
            frame = frame.loc[laps == best].reset_index(drop=True)
        elif lap_times_s is not None:
            raise UserInputError("the drive has no complete clean lap to cut from its trace")
    frame["time_s"] = frame["time_s"] - float(frame["time_s"].iloc[0])
    frame["distance_m"] = frame["distance_m"] - float(frame["distance_m"].iloc[0])
    return frame


def bot_trace(data: Any, part: str, track: str) -> tuple[str, pd.DataFrame] | None:
    """The follower bot's lap on ``track`` as the store keeps it
    (``<part>/_baselines/<bot>-<ref>-<track>/trace.parquet``, the ``baselines.path`` column), or
    None where no baseline drive stored one. The lap's ``attrs["reference"]`` names the line the
    bot followed (for the line figure's title)."""
    rows = data.baselines
    if rows.empty:
        return None
    sel = rows.loc[(rows["part"].astype(str) == part) & (rows["track"].astype(str) == track)]
    sel = sel.sort_values("bot", key=lambda b: b != "follower", kind="stable")
    for _, row in sel.iterrows():
        if not isinstance(row["path"], str) or not row["path"]:
            continue
        trace = data.read_baseline_trace(row["path"])
        if trace is None:
            continue
        if trace.empty or not {"distance_m", "speed_kmh", "x_m", "y_m"} <= set(trace.columns):
            data.problems.append(f"baseline trace {row['path']}: missing columns")
            continue
        label, _ = bot_row_label(rows, str(row["bot"]), str(row["reference"]))
        lap = one_lap(trace)
        lap.attrs["reference"] = str(row["reference"])
        return label, lap
    return None


def make_figures(ctx: Context, tables_: list[ReportTable],
                 out_dir: Path) -> dict[str, list[Path]]:
    """Draw every figure the tournament's results support; a figure whose inputs are missing is
    skipped and said in ``data.problems`` (never an exception for absent data)."""
    out_dir = Path(out_dir)
    figures: dict[str, list[Path]] = {}
    data = ctx.data
    models = ctx.models
    jobs = ctx.jobs
    train_of = dict(zip(jobs["job_id"].astype(str), jobs["train_tracks"], strict=True))

    for part in data.part_order():
        ep = data.episodes.loc[data.episodes["part"] == part]
        on_train = np.array([t in train_of.get(j, []) for j, t in
                             zip(models["job_id"], models["track"], strict=True)], dtype=bool)
        own = models.loc[(models["part"] == part).to_numpy(dtype=bool) & on_train]
        if ep.empty and own.empty:
            continue
        name = f"learning-{slug(part)}"
        figures[name] = plot_learning_curves(ep, own, f"Learning curves, {part}",
                                             out_dir / name)

    table3 = next((t for t in tables_ if t.key == "table3"), None)
    for rec in (table3.records if table3 is not None else []):
        label = rec["row"]
        sub = models.loc[models["job_id"].isin(rec["jobs"])]
        if sub.empty:
            continue
        tested = list(dict.fromkeys(sub["track"].astype(str)))
        # the train track first where the runs were tested on it (generated tracks are not)
        tracks = list(dict.fromkeys([rec["train_track"], *tested])) if (
            rec["train_track"] in tested) else tested
        general = rec.get("general")
        name = f"generalisation-{slug(label)}"
        figures[name] = plot_generalisation(sub, tracks, f"{label}: lap time on each track",
                                            out_dir / name, general)

    table1 = next((t for t in tables_ if t.key == "table1"), None)
    for rec in _group_leaders(table1.records if table1 is not None else []):
        group, job_id, track = rec["group"], rec["best_job"], rec["track"]
        trace = data.read_trace(job_id, track)
        if trace is None or trace.empty:
            data.problems.append(f"figure {group}: no trace for {job_id} on {track}")
            continue
        name = slug(group)
        label = f"{rec['row']} ({job_id.rsplit('/', 1)[-1]})"
        figures[f"trace-{name}"] = plot_action_trace(
            trace, f"{group}: fastest lap, {label}", out_dir / f"trace-{name}")
        rival = _rival(data, table1, rec)
        traces = {label: trace}
        lap_times = {label: rec["bLT"]}
        lines = [str(rec["reference"])]
        if rival is not None:
            traces[rival[0]] = rival[1]
            lap_times[rival[0]] = rival[2]
            lines.append(rival[3])
        figures[f"line-{name}"] = plot_racing_line(
            traces, f"{group}: paths driven, coloured by speed ({lines_driven(lines)})",
            out_dir / f"line-{name}", _load_track(track), lap_times)
        if rival is not None:
            figures[f"delta-{name}"] = plot_lap_delta(
                trace, rival[1], label, rival[0], f"{group}: lap vs lap",
                out_dir / f"delta-{name}")

    for pair in ablation_pairs(data):
        ep = data.episodes.loc[data.episodes["part"] == pair["part"]]
        labels = {pair["off"]: f"{pair['off']} ({pair['flag']} off)",
                  pair["on"]: f"{pair['on']} ({pair['flag']} on)"}
        name = f"ablation-{slug(pair['part'])}-{slug(pair['flag'])}"
        figures[name] = plot_ablation(ep, labels, f"Ablation of {pair['flag']}, {pair['part']}",
                                      out_dir / name)
    return figures


def lines_driven(kinds: list[str]) -> str:
    """What the drivers of a line figure followed, by the lines' labels (``lines.kinds``):
    ``both on the MOT line`` or ``on the MOT and RC lines``; a path is only a racing line where
    its driver followed one."""
    labels = list(dict.fromkeys(line_label(k) for k in kinds))
    if len(labels) == 1:
        return f"{'both' if len(kinds) > 1 else 'driven'} on the {labels[0]} line"
    return "on the " + " and ".join(labels) + " lines"


def _group_leaders(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The record with the lowest bLT in each Table 1 group."""
    best: dict[str, dict[str, Any]] = {}
    for rec in records:
        if rec.get("status") != "ok" or not math.isfinite(rec["bLT"]):
            continue
        cur = best.get(rec["group"])
        if cur is None or rec["bLT"] < cur["bLT"]:
            best[rec["group"]] = rec
    return list(best.values())


def _rival(data: Any, table1: ReportTable,
           leader: dict[str, Any]) -> tuple[str, pd.DataFrame, float, str] | None:
    """What to compare the fastest lap with, its lap time as Table 1 shows it and the line it
    followed: a stored follower-bot lap, else the runner-up entrant of the same column."""
    bot = bot_trace(data, leader["part"], leader["track"])
    if bot is not None:
        row = next((r for r in table1.rows if r["kind"] == "bot" and r["label"] == bot[0]), None)
        lap_s = row["values"].get((leader["group"], "bLT"), math.nan) if row else math.nan
        return bot[0], bot[1], float(lap_s), str(bot[1].attrs["reference"])
    others = [r for r in table1.records if r["group"] == leader["group"] and r is not leader
              and r.get("status") == "ok" and r.get("best_job")]
    for rec in sorted(others, key=lambda r: r["bLT"]):
        trace = data.read_trace(rec["best_job"], leader["track"])
        if trace is not None and not trace.empty:
            return (f"{rec['row']} ({rec['best_job'].rsplit('/', 1)[-1]})", trace, rec["bLT"],
                    str(rec["reference"]))
    return None
