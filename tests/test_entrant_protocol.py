"""The training loop drives any Entrant: ours (FamilyEntrant) and one defined here in NumPy alone.

``RandomWalker`` is what an outside package could write against ``agents.protocol`` alone: a
random policy whose "learning" is a running mean of the rewards it observes. Registered through
``agents.entrants.register_entrant_kind``, it trains through ``training.loop.train`` into a job
folder like ours; a faulty one (NaN, wrong shape) fails the job with a reason naming it.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pydantic
import pytest
from training_fixtures import SMALL

from formula_tourney.agents import entrants
from formula_tourney.agents.checkpoints import load_checkpoint
from formula_tourney.agents.family_entrant import FamilyEntrant
from formula_tourney.agents.protocol import Entrant, EntrantSpaces, Transition
from formula_tourney.agents.variants import get_variant
from formula_tourney.results.folder import JobFolder
from formula_tourney.safeio import atomic_write_text
from formula_tourney.training import loop
from formula_tourney.training.run_spec import RunSpec, build_run_spec


class WalkerSettings(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)
    throttle: float = pydantic.Field(0.6, ge=0.0, le=1.0, description="Greedy throttle.")
    fault: str = pydantic.Field("", description="'nan' or 'shape': return a bad action.")


class RandomWalker:
    """Uniform random exploration, a fixed greedy action, a running mean of rewards."""

    def __init__(self, settings: WalkerSettings, spaces: EntrantSpaces, seed: int) -> None:
        self.label = "tests.RandomWalker"
        self.window = 1
        self.settings, self.spaces = settings, spaces
        self.rng = np.random.default_rng(seed)
        self.seen = 0  # transitions observed over the run (its training state)
        self.steps_here = 0  # steps observed by this object (not resumed)
        self.mean_reward = 0.0
        self.started: list[int] = []

    @classmethod
    def settings_model(cls) -> type[pydantic.BaseModel]:
        return WalkerSettings

    @classmethod
    def build(cls, settings: Any, spaces: EntrantSpaces, seed: int, device: str) -> RandomWalker:
        return cls(settings, spaces, seed)

    def act(self, windows: np.ndarray) -> np.ndarray:
        action = np.zeros((len(windows), self.spaces.action_dim), np.float32)
        action[:, 1] = self.settings.throttle
        return action

    def explore(self, windows: np.ndarray, env_steps: int) -> np.ndarray:
        s = self.spaces
        action = self.rng.uniform(s.action_low, s.action_high, (len(windows), s.action_dim))
        if self.settings.fault == "nan" and env_steps >= 5:
            action[0, 0] = np.nan
        if self.settings.fault == "shape":
            return action[:, :2]
        return action.astype(np.float32)

    def observe(self, transitions: Sequence[Transition]) -> None:
        self.steps_here += 1
        for t in transitions:
            assert t.obs.shape == (self.spaces.obs_dim,) and np.isfinite(t.reward)
            self.seen += 1
            self.mean_reward += (t.reward - self.mean_reward) / self.seen

    def update(self, env_steps: int) -> dict[str, float]:
        return {"mean_reward": self.mean_reward}

    def episode_started(self, car: int) -> None:
        self.started.append(car)

    def save(self, path: Path) -> None:
        atomic_write_text(path, json.dumps({"throttle": self.settings.throttle}))

    @classmethod
    def load(cls, path: Path, device: str) -> RandomWalker:
        throttle = json.loads(Path(path).read_text())["throttle"]
        spaces = EntrantSpaces(1, 3, np.zeros(3, np.float32), np.ones(3, np.float32), 1)
        return cls(WalkerSettings(throttle=throttle), spaces, 0)

    def training_state(self) -> dict[str, Any]:
        return {"rng": self.rng.bit_generator.state, "seen": self.seen,
                "mean_reward": self.mean_reward}  # fmt: skip

    def restore_training_state(self, state: dict[str, Any]) -> None:
        self.rng.bit_generator.state = state["rng"]
        self.seen, self.mean_reward = int(state["seen"]), float(state["mean_reward"])


def _spec(**schedule: object) -> RunSpec:
    return build_run_spec(
        variant="WIN1", overrides=SMALL, train_tracks=["ring"], device="cpu", seed=2,
        schedule={"episodes": 3, "max_steps": 40, "test_every_episodes": 2, "test_starts": 2,
                  "test_max_steps": 30, **schedule},
    )  # fmt: skip


class Registration:
    """RandomWalker registered as every run's entrant: the settings it is built with, and the
    walkers built."""

    def __init__(self) -> None:
        self.settings = WalkerSettings()
        self.built: list[RandomWalker] = []

    def resolve(self, spec: RunSpec) -> tuple[type[Entrant], pydantic.BaseModel]:
        built = self.built

        class Recorded(RandomWalker):
            @classmethod
            def build(cls, settings: Any, spaces: EntrantSpaces, seed: int, device: str
                      ) -> RandomWalker:  # fmt: skip
                built.append(RandomWalker(settings, spaces, seed))
                return built[-1]

        return Recorded, self.settings


@pytest.fixture
def walker(monkeypatch: pytest.MonkeyPatch) -> Registration:
    """RandomWalker trains every run here (in a fresh registry: nothing leaks out)."""
    monkeypatch.setattr(entrants, "_KINDS", {})
    registration = Registration()
    entrants.register_entrant_kind("walker", registration.resolve)
    return registration


def test_family_entrant_is_an_entrant_and_resolves_by_default(ring_tracks: None) -> None:
    spec = _spec()
    spaces = EntrantSpaces(29, 3, np.zeros(3, np.float32), np.ones(3, np.float32), 1)
    entrant = FamilyEntrant.build(get_variant("WIN1"), spaces, seed=0, device="cpu")
    assert isinstance(entrant, Entrant)
    assert entrant.label == "WIN1 (ddpg)" and entrant.window == 1
    assert entrants.entrant_class(spec) is FamilyEntrant
    assert entrants.resolve_entrant(spec) == (FamilyEntrant, spec.agent)
    assert isinstance(RandomWalker(WalkerSettings(), spaces, 0), Entrant)


def test_an_outside_entrant_trains_through_the_loop(
    tmp_path: Path, ring_tracks: None, walker: Registration
) -> None:
    summary = loop.train(_spec(), tmp_path / "job")
    (built,) = walker.built
    folder = JobFolder(tmp_path / "job")
    tests = folder.tests()
    episodes = pd.read_parquet(tmp_path / "job" / "episodes.parquet")
    assert summary["episodes"] == 3 and folder.is_finished()
    assert len(tests) == 4 and set(tests["episode"]) == {2, 3}  # two rounds of two starts
    assert built.seen == summary["env_steps"] == episodes["env_steps"].iloc[-1] > 0
    assert built.started == [0, 0, 0]  # each episode's start
    assert (episodes["updates"] == 0).all() and episodes["epsilon"].isna().all()
    saved = json.loads((tmp_path / "job" / "checkpoints" / "last.pt").read_text())
    assert saved == {"throttle": 0.6}


def test_an_outside_entrant_resumes_bit_for_bit(
    tmp_path: Path, ring_tracks: None, walker: Registration
) -> None:
    spec = _spec(resume_every_cpu_s=1e-6)  # a resume file at every step
    job = tmp_path / "job"

    def abandon(info: dict) -> None:
        if info["episode"] == 2 and JobFolder(job).resume_path.exists():
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        loop.train(spec, job, abandon)
    loop.train(spec, job)
    loop.train(spec, tmp_path / "whole")
    resumed, whole = walker.built[1:]
    assert resumed.seen == whole.seen and 0 < resumed.steps_here < whole.steps_here
    for name in ("episodes", "tests"):
        a, b = (JobFolder(p).table(name).drop(columns=["seconds", "cpu_s"], errors="ignore")
                for p in (job, tmp_path / "whole"))  # fmt: skip
        pd.testing.assert_frame_equal(a, b, check_exact=True)


@pytest.mark.parametrize(
    ("fault", "reason"),
    [("nan", "entrant tests.RandomWalker returned a NaN or infinite action"),
     ("shape", r"entrant tests.RandomWalker returned actions of shape \(1, 2\) and dtype "
               r"float64, not \(1, 3\) numbers")],
)  # fmt: skip
def test_a_bad_action_fails_the_job_naming_the_entrant(
    tmp_path: Path, ring_tracks: None, walker: Registration, fault: str, reason: str
) -> None:
    walker.settings = WalkerSettings(fault=fault)
    with pytest.raises(loop.EntrantError, match=f"^{reason}$"):
        loop.train(_spec(), tmp_path / "job")
    assert not JobFolder(tmp_path / "job").is_finished()


def test_our_checkpoints_keep_their_format(tmp_path: Path, ring_tracks: None) -> None:
    loop.train(_spec(), tmp_path / "job")
    path = tmp_path / "job" / "checkpoints" / "last.pt"
    agent, extra = load_checkpoint(path)
    assert extra["episode"] == 3 and extra["run_spec"]["variant"] == "WIN1"
    assert agent.updates > 0
    entrant = FamilyEntrant.load(path, "cpu")  # drives what the checkpoint's agent drives
    windows = np.random.default_rng(0).normal(size=(2, 1, agent.obs_dim)).astype(np.float32)
    expected = np.stack([agent.act_eval(w) for w in windows])
    np.testing.assert_array_equal(entrant.act(windows), expected)
