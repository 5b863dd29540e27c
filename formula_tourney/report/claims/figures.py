"""Figures drawn from the claims' data: what a reader needs to see behind a verdict.

- ``claim-<id>`` for a reward claim (the adopted-target ablation): both groups' training reward,
  mean over runs with a 95 % band (``plots.plot_ablation``; B green, A red as in the paper).
- ``claim-<id>-<side>-<config>`` for a finish claim: lap time on every test track vs training
  episode for each configuration of that side, its general model marked in red
  (``plots.plot_generalisation`` with ``paper_tables.general_model_of``: the tables' choice).
- ``profile``: the performance profile of every run of the tournament (lap / reference limit,
  ``report.claims.profiles``), one curve with its band per entrant.

A claim without runs draws nothing (its verdict already says "no data").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from formula_tourney.report.claims import profiles
from formula_tourney.report.claims.entrants import entrants, first_train_track
from formula_tourney.report.claims.evaluate import ClaimResult
from formula_tourney.report.paper_tables import Context, general_model_of
from formula_tourney.report.plots import (
    _pyplot,
    plot_ablation,
    plot_generalisation,
    save_figure,
    subplots,
    wrap,
)
from formula_tourney.report.plots import slug as _slug


def plot_performance_profile(ratios: pd.DataFrame, title: str, out_base: Path) -> list[Path]:
    """Fraction of runs with lap / reference limit <= tau, per entrant, and over all runs where
    they share one setup, with 95 % bootstrap bands (rliable's performance profile). Entrant
    labels name their setup and are long: the legend sits below the axes, one per line."""
    plt = _pyplot()
    groups = [(g, grp["ratio"].to_numpy(dtype=float)) for g, grp in
              ratios.groupby("group", sort=False)]
    if ratios["setup"].nunique() == 1:  # runs of two presets are never pooled
        groups.append(("all runs", ratios["ratio"].to_numpy(dtype=float)))
    fig, ax = subplots(figsize=(8, 4.5 + 0.3 * len(groups)))
    taus = profiles.tau_grid(ratios["ratio"].to_numpy(dtype=float))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (name, values) in enumerate(groups):
        mid, low, high = profiles.profile_band(values, taus)
        colour = "black" if name == "all runs" else colours[k % len(colours)]
        ax.step(taus, mid, where="post", color=colour, lw=2.0 if name == "all runs" else 1.2,
                label=wrap(f"{name} (n={values.size})", 3.5, 7))
        if values.size > 1:
            ax.fill_between(taus, low, high, step="post", color=colour, alpha=0.15, lw=0)
    ax.fill_between([], [], color="0.5", alpha=0.3, lw=0, label="95% bootstrap CI (shaded)")
    ax.set_xlabel("tau = best clean lap / reference limit")
    ax.set_ylabel("fraction of runs with ratio <= tau")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(wrap(title, 7.5, 12))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=1, loc="upper left", bbox_to_anchor=(0.0, -0.14),
              frameon=False)
    return save_figure(fig, out_base)


def _reward_figure(ctx: Context, res: ClaimResult, out_dir: Path) -> dict[str, list[Path]]:
    comp_a = sorted({j for c in res.comparisons for j in c.a_runs})
    comp_b = sorted({j for c in res.comparisons for j in c.b_runs})
    if not comp_a or not comp_b:
        return {}
    ep = ctx.data.episodes
    label_a = f"A: {res.claim.a.describe()}"
    label_b = f"B: {res.claim.b.describe()}"
    frames = [ep.loc[ep["job_id"].isin(ids)].assign(entrant=label)
              for ids, label in ((comp_b, label_b), (comp_a, label_a))]
    name = f"claim-{_slug(res.claim.id)}"
    return {name: plot_ablation(pd.concat(frames, ignore_index=True),
                                {label_b: label_b, label_a: label_a},
                                f"{res.claim.id}: {res.verdict}", out_dir / name,
                                smooth=res.claim.smooth)}


def _generalisation_figures(ctx: Context, res: ClaimResult,
                            out_dir: Path) -> dict[str, list[Path]]:
    out: dict[str, list[Path]] = {}
    jobs = ctx.jobs.set_index("job_id", drop=False)
    for side in ("a", "b"):
        ids = sorted({j for c in res.comparisons for j in getattr(c, f"{side}_runs")})
        if not ids:
            continue
        sub = jobs.loc[ids]
        for entrant in entrants(ctx, sub):  # one figure per entrant: never two presets in one
            job_ids = [str(j) for j in entrant.jobs["job_id"]]
            models = ctx.models.loc[ctx.models["job_id"].isin(job_ids)]
            if models.empty:
                continue
            train = first_train_track(entrant.jobs.iloc[0])
            tracks = list(dict.fromkeys([train, *models["track"].astype(str)]))
            rate = ctx.data.unseen_finish_rate(sub.loc[job_ids, "part"].astype(str))
            general = general_model_of(ctx, job_ids, train, tracks, rate)
            label = entrant.label
            name = f"claim-{_slug(res.claim.id)}-{side}-{_slug(label)}"
            out[name] = plot_generalisation(models, tracks, f"{res.claim.id} {side.upper()}: "
                                            f"{label}", out_dir / name, general)
    return out


def make_claim_figures(ctx: Context, results: list[ClaimResult],
                       out_dir: Path) -> dict[str, list[Path]]:
    """Every figure the claims' data supports, plus the tournament's performance profile."""
    out_dir = Path(out_dir)
    figures: dict[str, list[Path]] = {}
    for res in results:
        if res.claim.kind == "higher_reward":
            figures.update(_reward_figure(ctx, res, out_dir))
        elif res.claim.kind == "finishes_more":
            figures.update(_generalisation_figures(ctx, res, out_dir))
    ratios = profiles.run_ratios(ctx)
    if not ratios.empty and np.isfinite(ratios["ratio"]).any():
        figures["profile"] = plot_performance_profile(
            ratios, f"Performance profile, {ctx.data.name}: one curve per entrant",
            out_dir / "profile")
    return figures
