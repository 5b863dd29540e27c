"""The reward model: every setting and part of the reward, declared once, in one table.

The reward a transition is stored with has two stages:

1. The env's reward per step, computed in the compiled step (``kernels.score_step``): the
   paper's ``Vx (cos(theta) - |sin(theta)| - w |trackPos|)``, or beyond the paper the progress
   along the track in place of its speed term; minus ``damage_weight`` times the damage of the
   step; replaced on a step that ends the episode early by the end's own reward.
2. The training collector's rule (:class:`RewardRule`): less ``crash_penalty`` on an early end,
   times ``reward_scale``.

:data:`SETTINGS` declares each setting and constant of both stages once (name, default, bounds,
description, whether it is beyond the paper, the layout that added it). The models that hold a
run's values build their Fields from it (:meth:`RewardSetting.field`): the env's in
``sim.config.EnvSettings``, the training stage's in ``agents.variants.AgentConfig`` (where the
run specification has always stored them, so existing ``config.json`` files and config hashes
stay as they were). The kernel's weights are packed in the table's order (:func:`pack`); the
kernel's ``C_*`` indices are derived from :data:`KERNEL_NAMES`, so a new weight needs no index
written by hand. :class:`RewardParts` is ``info["rewards"]``: the step's reward split into
:data:`PARTS`, recomputed from what the kernel wrote (:data:`INPUT_NAMES`) only when read, so
the step pays for a copy of a few floats and nothing more.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

import numpy as np
from pydantic import Field

from formula_tourney.field_marks import marks

Home = Literal["env", "agent", "fixed"]
RewardLike = TypeVar("RewardLike", float, np.ndarray)


@dataclass(frozen=True)
class RewardSetting:
    """One setting (or constant) of the reward: declared here, held by the model of its ``home``.

    ``home``: ``env`` a key of ``sim.config.EnvSettings``, ``agent`` a key of
    ``agents.variants.AgentConfig`` (the training stage), ``fixed`` a constant no run changes.
    ``kernel``: the compiled step reads it (packed by :func:`pack`).
    """

    name: str
    default: float | bool
    description: str
    home: Home
    kernel: bool
    beyond_paper: bool = False
    added_in_layout: int | None = None
    ge: float | None = None
    gt: float | None = None
    le: float | None = None

    def field(self) -> Any:
        """The pydantic Field of this setting in the model that holds a run's value."""
        extra = marks(added_in_layout=self.added_in_layout, beyond_paper=self.beyond_paper)
        return Field(self.default, ge=self.ge, gt=self.gt, le=self.le,
                     description=self.description, json_schema_extra=extra or None)


SETTINGS: tuple[RewardSetting, ...] = (
    RewardSetting(
        "track_pos_weight", 1.0, home="env", kernel=True, beyond_paper=True, added_in_layout=2,
        ge=0.0, le=10.0,
        description="Weight w of the reward's -Vx w |trackPos| term. The paper's 1 pays a car "
        "for staying on the reference line, which caps its lap at that line's limit; below 1 "
        "(beyond the paper) the car may take its own line across the track.",
    ),
    RewardSetting(
        "progress_reward", False, home="env", kernel=True, beyond_paper=True, added_in_layout=2,
        description="Beyond the paper: the reward's speed term is the car's progress along the "
        "track (metres of centreline per second, what a lap time counts) instead of the paper's "
        "Vx (cos(theta) - |sin(theta)|) along the reference line, which pays only for speed "
        "along that line and so for a longer way round a corner as much as a shorter one. The "
        "line term -Vx w |trackPos| and the damage term stay.",
    ),
    RewardSetting(
        "damage_weight", 0.01, home="env", kernel=True, ge=0.0,
        description="Reward term: minus this times the damage taken in the step.",
    ),
    RewardSetting(
        "slow_penalty", 100.0, home="env", kernel=True, ge=0.0,
        description="Reward on a slow end is -slow_penalty: a slow end without penalty taught "
        "a run to stop on track (docs/sim.md, Env).",
    ),
    RewardSetting(
        "early_end_reward", -1.0, home="fixed", kernel=True,
        description="The reward of a step that ends the episode off track or backwards (the "
        "paper's -1).",
    ),
    RewardSetting(
        "wall_energy_weight", 0.0, home="env", kernel=True, beyond_paper=True,
        added_in_layout=2, ge=0.0, le=10.0,
        description="Beyond the paper: the kinetic-energy wall penalty of Fuchs et al. (2021, "
        "Gran Turismo Sport): an episode that ends off track also pays minus this times Vx^2 "
        "(m^2/s^2) at the step it left, so leaving the track at speed costs more than leaving "
        "it slowly and the critic has a reason to arrive at a corner slower; 0: the paper's "
        "-1, bit for bit.",
    ),
    RewardSetting(
        "overspeed_crash_weight", 0.0, home="env", kernel=True, beyond_paper=True,
        added_in_layout=2, ge=0.0, le=10.0,
        description="Beyond the paper: an episode that ends off track also pays minus this "
        "times twice the kinetic energy per kilogram above the reference limit's, (Vx^2 - "
        "v_limit^2) (m^2/s^2) when positive, where v_limit is the QSS speed of the "
        "minimum-curvature line at the sample where the car left. Unlike a flat crash penalty "
        "or the wall energy term, a car that leaves the track at or below the limit's speed "
        "(a slip at the limit, a slow mistake) pays only the paper's -1; arriving at a corner "
        "far too fast costs in proportion. A training run fills v_limit per track sample "
        "(limit_speeds_mps); 0: the paper's -1, bit for bit.",
    ),
    RewardSetting(
        "reward_scale", 0.02, home="agent", kernel=False, gt=0.0,
        description="Rewards are multiplied by this before they enter the replay buffer. The "
        "paper's reward is Vx in m/s per step (up to ~80), so Q reaches thousands; scaled, the "
        "critic starts near its targets' size.",
    ),
    RewardSetting(
        "crash_penalty", 0.0, home="agent", kernel=False, beyond_paper=True, added_in_layout=2,
        ge=0.0, le=100_000.0,
        description="Beyond the paper: subtracted from the reward (env units, before "
        "reward_scale) of every transition that ends its episode early (off track, backwards, "
        "slow), so the critic sees a crash as costlier than the paper's -1 plus the lost "
        "future; 0: the paper's rewards, stored bit for bit as before.",
    ),
    RewardSetting(
        "crash_penalty_decay_steps", 0, home="agent", kernel=False, beyond_paper=True,
        added_in_layout=2, ge=0, le=100_000_000,
        description="Beyond the paper: the crash penalty falls linearly from crash_penalty at "
        "the first env step to 0 at this many env steps (the step a transition is stored at), "
        "so that it can help a run learn to lap and then leave the fast laps alone (on the "
        "oval, 100 000 steps cost the best lap as much as a penalty kept all run: "
        "docs/results.md); 0: the penalty stays for the whole run.",
    ),
)
"""Every setting and constant of the reward, in the order the kernel's weights are packed."""

BY_NAME: dict[str, RewardSetting] = {s.name: s for s in SETTINGS}

KERNEL_NAMES: tuple[str, ...] = tuple(s.name for s in SETTINGS if s.kernel)
"""The weights the compiled step reads, in the order of their block of the kernel's config."""

INPUT_NAMES: tuple[str, ...] = (
    "reward", "end", "damage", "speed_mps", "angle_rad", "track_pos", "progress_mps",
)
"""What the compiled step writes per car for the reward, in the order of its output block:
the reward, the end code (0 while running), the damage of the step, the body speed Vx (m/s),
the angle to the reference line (rad), trackPos and the progress along the track (m/s)."""

PARTS: dict[str, str] = {
    "along": "Vx cos(theta): the paper's speed along the reference line (0 with progress_reward).",
    "sideways": "-Vx |sin(theta)|: the paper's cost of driving at an angle to the reference "
    "line (0 with progress_reward).",
    "progress": "Beyond the paper, with progress_reward: the progress along the track in m/s, "
    "in place of along and sideways.",
    "track_pos": "-track_pos_weight Vx |trackPos|: the cost of leaving the reference line.",
    "damage": "-damage_weight times the damage taken in the step.",
    "end": "On a step that ends the episode early, its reward (early_end_reward off track or "
    "backwards, less wall_energy_weight Vx^2 and overspeed_crash_weight max(0, Vx^2 - "
    "v_limit^2) off track; -slow_penalty slow), which replaces every other part (they read 0).",
}
"""The keys of ``info["rewards"]`` and what each pays; they sum to the step's reward."""


def kernel_slot(name: str) -> int:
    """Where weight ``name`` sits in the kernel's reward block (its place in the table)."""
    return KERNEL_NAMES.index(name)


def input_slot(name: str) -> int:
    """Where input ``name`` sits in the kernel's per-car reward output block."""
    return INPUT_NAMES.index(name)


def pack(settings: Any, block: np.ndarray) -> None:
    """Write the kernel's weights from ``settings`` (an ``EnvSettings``) into ``block``, in
    :data:`KERNEL_NAMES` order; a fixed constant takes its default, a switch 1.0 or 0.0."""
    for k, name in enumerate(KERNEL_NAMES):
        s = BY_NAME[name]
        block[k] = float(s.default if s.home == "fixed" else getattr(settings, name))


def parts(weights: np.ndarray, inputs: np.ndarray) -> dict[str, Any]:
    """The step's reward split into :data:`PARTS`, from the packed ``weights`` and the kernel's
    ``inputs`` (one row, or one row per car: then each part is an array over cars)."""
    w = {name: float(weights[k]) for k, name in enumerate(KERNEL_NAMES)}
    x = {name: inputs[..., k] for k, name in enumerate(INPUT_NAMES)}
    ended = x["end"] != 0.0
    vx = np.where(ended, 0.0, x["speed_mps"])
    zero = np.zeros_like(vx)
    if w["progress_reward"] > 0.5:
        along, sideways = zero, zero
        progress = np.where(ended, 0.0, x["progress_mps"])
    else:
        along = vx * np.cos(x["angle_rad"])
        sideways = -vx * np.abs(np.sin(x["angle_rad"]))
        progress = zero
    out = {
        "along": along,
        "sideways": sideways,
        "progress": progress,
        "track_pos": -vx * (w["track_pos_weight"] * np.abs(x["track_pos"])),
        "damage": np.where(ended, 0.0, -w["damage_weight"] * x["damage"]),
        "end": np.where(ended, x["reward"], 0.0),
    }
    # (+ 0.0 turns the -0.0 of a part that pays nothing into 0.0)
    if inputs.ndim == 1:
        return {k: float(v) + 0.0 for k, v in out.items()}
    return {k: v + 0.0 for k, v in out.items()}


class RewardParts(Mapping[str, Any]):
    """``info["rewards"]``: part -> value of the step (highway-env's ``info["rewards"]``), so a
    user sees what a policy is paid for; the parts sum to the reward.

    Holds a copy of the kernel's inputs and splits the reward on first read: a step whose info
    nobody reads pays for the copy alone.
    """

    __slots__ = ("_weights", "_inputs", "_parts")

    def __init__(self, weights: np.ndarray, inputs: np.ndarray) -> None:
        self._weights = weights
        self._inputs = inputs
        self._parts: dict[str, Any] | None = None

    def _split(self) -> dict[str, Any]:
        if self._parts is None:
            self._parts = parts(self._weights, self._inputs)
        return self._parts

    def __getitem__(self, key: str) -> Any:
        return self._split()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(PARTS)

    def __len__(self) -> int:
        return len(PARTS)

    def __repr__(self) -> str:
        return f"RewardParts({self._split()!r})"


@dataclass(frozen=True)
class RewardRule:
    """How the env's reward becomes the reward a transition is stored with: less
    ``crash_penalty`` on an early end, times ``scale`` (a run's ``reward_scale``). The one owner
    of that rule: both collectors and the demonstrations store through it, so a demonstration
    and an own transition weigh alike. Without a penalty the product is the paper's, bit for
    bit."""

    scale: float = 1.0
    crash_penalty: float = 0.0
    decay_steps: int = 0

    @classmethod
    def of(cls, settings: Any) -> RewardRule:
        """The rule a run's settings declare (an ``AgentConfig``: the keys of the ``agent``
        home of :data:`SETTINGS`), at its first env step."""
        return cls(scale=settings.reward_scale, crash_penalty=settings.crash_penalty,
                   decay_steps=settings.crash_penalty_decay_steps)

    @property
    def decays(self) -> bool:
        """Whether the penalty changes with the env steps (:meth:`at`)."""
        return bool(self.crash_penalty and self.decay_steps)

    def at(self, env_steps: int) -> RewardRule:
        """The fixed rule for a transition stored after ``env_steps`` env steps: the penalty
        falls linearly to 0 at ``decay_steps``. The result does not decay again (a rule that
        does not decay is returned as it is)."""
        if not self.decays:
            return self
        left = max(0.0, 1.0 - env_steps / self.decay_steps)
        return RewardRule(self.scale, self.crash_penalty * left)

    def __call__(self, reward: RewardLike, terminated: bool | np.ndarray) -> RewardLike:
        """The stored reward(s) of a step: a float and a bool, or arrays over cars."""
        if self.crash_penalty:
            reward = reward - self.crash_penalty * np.asarray(terminated, dtype=np.float64)
        return reward * self.scale
