"""The claim model: what a ``[claims]`` table (tournament file) or a claims file declares.

A claim compares two groups of runs, A and B (or a group with a baseline bot), on one measure:
``faster`` (each run's best clean lap on a track), ``finishes_more`` (the share of unseen test
tracks a run laps cleanly) or ``higher_reward`` (the highest moving average of a run's training
reward, the paper's Figure 6 reading). Groups are selected by the index's columns (part,
entrant, variant, family, reference, lac, train track) and by run-spec settings (e.g.
``adopted_target = false``), so one claim reads the same on any tournament that ran those runs.

This module sits below ``tourney.spec`` (which embeds a :class:`ClaimSet` as ``[claims]``) and
the report (which evaluates it); it imports nothing of either. Every field has a description,
so error messages and docs/claims.md read from one place.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from formula_tourney.errors import UserInputError
from formula_tourney.lines.kinds import LineKind, ReferenceKind
from formula_tourney.safeio import check_name

SETS_DIR = Path(__file__).resolve().parent
"""Folder of the shipped claim sets (``<name>.toml``)."""
SHIPPED_SETS: tuple[str, ...] = tuple(sorted(p.stem for p in SETS_DIR.glob("*.toml")))
"""Names a ``include`` may list: the shipped sets (``paper``: the paper's six findings)."""

Kind = Literal["faster", "finishes_more", "higher_reward", "learns_faster"]
Milestone = Literal["first_clean_lap", "beat_centre_bot", "beat_mincurv_bot"]
"""What a learns_faster claim times (``results.competence.MILESTONES``): the first clean lap,
beating the follower on the centre line, beating it on the min-curvature line."""
DecideOn = Literal["mean", "wins"]
"""What a claim's anytime-valid verdict reads (``claims.sequential``): the mean of the paired
differences, or the pairs A wins (the probability of improvement against one half)."""
SplitBy = Literal["none", "family", "variant", "entrant"]
PairKey = Literal["part", "variant", "reference", "lac", "train_track"]
PoolKey = Literal["variant", "line", "train_track", "setup"]
"""What makes runs one entrant (``report.claims.entrants``); a claim may pool runs across them."""
RUN_SELECTORS: tuple[str, ...] = ("part", "entrant", "variant", "family", "preset",
                                  "beyond_paper", "reference", "lac", "train_track",
                                  "settings")  # fmt: skip


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _as_list(value: Any) -> Any:
    """A single name where a list is allowed (``variant = "PER1M"``) becomes a list of one."""
    return [value] if isinstance(value, str) else value


class Group(_Strict):
    """One side of a claim: the runs matching every given selector, or a baseline bot."""

    label: str | None = Field(None, description="Name shown for this group (default: built "
                              "from its selectors).")
    part: list[str] | None = Field(None, description="Parts whose runs count (name or list).")
    entrant: list[str] | None = Field(None, description="Entrant names (e.g. PER1M-RC-LAC); "
                                      "shell patterns such as WIN* allowed.")
    variant: list[str] | None = Field(None, description="Variant names (e.g. WIN1, PER1M); "
                                      "shell patterns allowed.")
    family: list[str] | None = Field(None, description="Families (DDPG, LSTM, MS, PER, TD3, "
                                     "SAC; or a tournament's own).")
    preset: list[str] | None = Field(None, description="Presets the runs started from "
                                     "(paper, fast-small, tuned, tuned-bc, ...); shell patterns "
                                     "allowed.")
    beyond_paper: list[str] | None = Field(
        None, description="What the runs add to the paper's setup, as the tables label it "
        "(e.g. \"preset tuned-bc\", \"demos (follower on mincurv)\"): each pattern must match "
        "one of a run's labels (shell patterns, e.g. \"demos*\"); [] selects runs of the "
        "paper's own setup only.")
    reference: list[ReferenceKind] | None = Field(
        None, description="Reference lines of the runs: centre (MOT), recorded (RC), mincurv.")
    lac: bool | None = Field(None, description="Runs with (true) or without (false) look-ahead "
                             "curvature.")
    train_track: list[str] | None = Field(None, description="The runs' first train track "
                                          "(where their lap times count).")
    settings: dict[str, bool | int | float | str] | None = Field(
        None, description="Run-spec agent or env settings the runs must have, e.g. "
        "{ adopted_target = false }.")
    bot: Literal["follower", "genetic"] | None = Field(
        None, description="Instead of runs: a baseline bot's best clean lap (one value, no "
        "spread); only for kind = faster.")
    bot_reference: LineKind | None = Field(
        None, description="Line the bot drove (default: its best over the lines it drove).")

    _listify = field_validator("part", "entrant", "variant", "family", "preset",
                               "beyond_paper", "reference", "train_track",
                               mode="before")(_as_list)

    @model_validator(mode="after")
    def _bot_or_runs(self) -> Group:
        chosen = [k for k in RUN_SELECTORS if getattr(self, k) is not None]
        if self.bot is not None and chosen:
            raise ValueError(f"a bot group takes no run selectors (got {', '.join(chosen)})")
        if self.bot is None and self.bot_reference is not None:
            raise ValueError("bot_reference needs bot")
        return self

    @property
    def is_bot(self) -> bool:
        return self.bot is not None

    def describe(self) -> str:
        """The group in words (its label, else its selectors)."""
        if self.label:
            return self.label
        if self.bot is not None:
            return f"{self.bot} bot" + (f" ({self.bot_reference})" if self.bot_reference else "")
        bits = []
        for key in RUN_SELECTORS:
            value = getattr(self, key)
            if value is None:
                continue
            if key == "beyond_paper" and not value:
                bits.append("the paper's setup")
            elif isinstance(value, list):
                bits.append(f"{key} {'/'.join(map(str, value))}")
            elif isinstance(value, dict):
                bits.append(", ".join(f"{k}={v}" for k, v in value.items()))
            else:
                bits.append(f"{key} {value}")
        return "; ".join(bits) or "all runs"


class Claim(_Strict):
    """One finding as a comparison: A is better than B on a measure."""

    id: str = Field(description="Short unique name of the claim (letters, digits, - and _).")
    statement: str = Field(description="The finding in words, as the report prints it.")
    source: str = Field("", description="Where the finding comes from (e.g. paper finding 2).")
    kind: Kind = Field(description="Measure: faster (best clean lap, lower is better), "
                       "finishes_more (share of unseen test tracks lapped cleanly), "
                       "higher_reward (highest moving average of the training reward) or "
                       "learns_faster (fewer CPU-seconds of training to the milestone; a "
                       "run that misses it counts as its CPU budget).")
    milestone: Milestone | None = Field(
        None, description="learns_faster: the milestone timed: first_clean_lap, "
        "beat_centre_bot or beat_mincurv_bot (the follower on that line, raced as a baseline "
        "of the runs' part).")
    bound: float | None = Field(
        None, gt=0.0, allow_inf_nan=False,
        description="For the anytime-valid confidence sequence (claims.sequential), which needs "
        "bounded scores: faster: how many seconds above the track's reference limit a lap "
        "counts at most (default: one limit; a slower lap and a miss count as that lap); "
        "higher_reward: the largest difference between a run of A and one of B (default: the "
        "range the scores span). Shares lie in [0, 100] and CPU-s to a milestone in [0, "
        "budget] by themselves.")
    decide_on: DecideOn = Field(
        "mean", description="What the anytime-valid (sequential) verdict reads: mean (the "
        "mean of the paired differences A - B, bounded as `bound` says) or wins (each pair "
        "+1 where A's run beats B's, -1 where it loses, 0 on a tie: supported when a run of A "
        "beats a run of B more often than not, the sign test; no bound needed, a miss loses "
        "to any result). The fixed-sample verdict reads the mean either way.")
    a: Group = Field(description="The group claimed to be better.")
    b: Group = Field(description="The group it is compared with.")
    track: str = Field("own", description="faster: the track lap times are read on; 'own': each "
                       "A run's first train track.")
    per_track: bool = Field(False, description="One comparison per train track of A's runs; "
                            "the claim holds only if it holds on every one (e.g. 'on every "
                            "track').")
    split_b: SplitBy = Field("none", description="Split B into one group per family, variant "
                             "or entrant: A must beat each (e.g. 'the best family').")
    pair_on: list[PairKey] = Field(default_factory=list, description="Compare only runs of A "
                                   "and B that share these values (e.g. part, variant).")
    pool: list[PoolKey] = Field(
        default_factory=list, description="What may differ among one side's runs and still "
        "make one sample. Unpooled, each side is split into entrants, runs alike in variant "
        "(the tables' row name), line (reference line and LAC), train_track and setup (preset "
        "and every other beyond-paper label); each entrant of A is compared with each of B's "
        "with the same setup, and the claim holds only if every comparison supports it. "
        "E.g. pool = [\"variant\"]: the WIN family as one group; pool = [\"setup\"]: compare "
        "across presets.")
    smooth: int = Field(20, ge=1, le=1000, description="higher_reward: moving-average window "
                        "in episodes.")

    @field_validator("id")
    @classmethod
    def _safe_id(cls, value: str) -> str:
        try:
            return check_name(value, "claim id")
        except UserInputError as err:
            raise ValueError(str(err)) from None

    @model_validator(mode="after")
    def _consistent(self) -> Claim:
        if self.a.is_bot and self.b.is_bot:
            raise ValueError("a claim compares runs: a and b cannot both be bots")
        if (self.a.is_bot or self.b.is_bot) and self.kind != "faster":
            raise ValueError(f"a bot has lap times only: kind {self.kind!r} needs runs on both "
                             "sides (allowed with a bot: faster)")
        if self.b.is_bot and self.split_b != "none":
            raise ValueError("split_b needs runs in b, not a bot")
        if (self.kind == "learns_faster") != (self.milestone is not None):
            raise ValueError("kind = \"learns_faster\" needs a milestone (first_clean_lap, "
                             "beat_centre_bot, beat_mincurv_bot), and a milestone needs that kind")
        if self.kind == "learns_faster" and self.track != "own":
            raise ValueError("a milestone is timed on each run's own train track: leave track "
                             "at 'own'")
        if self.per_track and self.track != "own":
            raise ValueError("per_track compares on each A run's own train track: leave track "
                             "at 'own'")
        return self


class ClaimSet(_Strict):
    """A ``[claims]`` table of a tournament file, or a whole claims file."""

    include: list[str] = Field(default_factory=list, description="Shipped claim sets to "
                               "include first (paper: the paper's six findings).")
    claim: list[Claim] = Field(default_factory=list, description="Claims, as [[claim]] tables "
                               "(in a tournament file: [[claims.claim]]).")

    @field_validator("include")
    @classmethod
    def _known_sets(cls, value: list[str]) -> list[str]:
        for name in value:
            if name not in SHIPPED_SETS:
                raise ValueError(f"unknown claim set {name!r}; allowed values: "
                                 f"{', '.join(SHIPPED_SETS)}")
        return value

    @model_validator(mode="after")
    def _unique_ids(self) -> ClaimSet:
        seen: set[str] = set()
        for claim in self.claim:
            if claim.id in seen:
                raise ValueError(f"claim id {claim.id!r} is used twice")
            seen.add(claim.id)
        return self

    def resolved(self) -> list[Claim]:
        """Included sets' claims first, then this set's; an own claim replaces an included
        claim of the same id (so a tournament can restate one paper finding)."""
        own = {c.id: c for c in self.claim}
        out: list[Claim] = []
        for name in self.include:
            out.extend(own.pop(c.id, c) for c in shipped_set(name).resolved())
        return [*out, *(c for c in self.claim if c.id in own)]


def shipped_set(name: str) -> ClaimSet:
    """A shipped claim set by name; a broken shipped file is a bug, said with its problems."""
    if name not in SHIPPED_SETS:
        raise UserInputError(f"unknown claim set {name!r}; allowed values: "
                             f"{', '.join(SHIPPED_SETS)}")
    path = SETS_DIR / f"{name}.toml"
    try:
        return ClaimSet.model_validate(tomllib.loads(path.read_text(encoding="utf-8")))
    except (tomllib.TOMLDecodeError, ValidationError) as err:
        raise RuntimeError(f"shipped claim set {path} is invalid: {err}") from None
