"""Stable-Baselines3 and sb3-contrib algorithms as entrants: any algorithm by name, fed by our loop.

The model is built on a minimal gymnasium env that only carries the run's spaces: SB3 never
steps it. ``training.loop`` steps the cars and hands each step's transitions to ``observe``, so
an SB3 algorithm learns from exactly the transitions (reward rule, random starts, cars) our
families learn from, tested by the same protocol. Off-policy algorithms (SAC, TD3, DDPG, TQC,
CrossQ) get each transition in ``model.replay_buffer`` (the action scaled to [-1, 1], as SB3
stores it; a time-limit cut marked so SB3 bootstraps through it) and ``model.train`` after
``learning_starts``, every ``train_freq`` with ``gradient_steps``, as ``OffPolicyAlgorithm.learn``
does. On-policy algorithms (PPO, A2C) sample their own actions with values and log-probabilities
in ``explore``, fill ``model.rollout_buffer`` one row per step of all cars (a time-limit cut
bootstrapped with the value of its last state) and train when ``n_steps`` rows are in.

SB3 writes nothing here: its logger has no outputs, ``tensorboard_log`` and ``verbose`` are
the adapter's, and there are no monitor files. ``save`` writes SB3's own zip (plus a small JSON
member naming the library and algorithm); ``load`` reads it with SB3's ``load``, which unpickles
parts of the file, so only files a run wrote must be loaded (the races and replays check that
the file lies in a job folder of a results folder). The extra is imported lazily, here only:
without it, the error names ``pip install formula-tourney[sb3]``.
"""

from __future__ import annotations

import copy
import importlib
import importlib.metadata
import inspect
import io
import json
import random
import zipfile
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pydantic
import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator

from formula_tourney.agents.protocol import EntrantSpaces, Transition
from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write_bytes

EXTRA_HINT = "pip install formula-tourney[sb3]"
"""How a user gets the optional extra (stable-baselines3 and sb3-contrib)."""

LIBRARIES: dict[str, tuple[str, str]] = {
    "sb3": ("stable_baselines3", "stable-baselines3"),
    "sb3_contrib": ("sb3_contrib", "sb3-contrib"),
}
"""Tournament key -> (module, distribution name) of each supported library."""

OWNED_KWARGS: dict[str, str] = {
    "policy": "the adapter builds MlpPolicy (shape it with policy_kwargs)",
    "env": "the loop steps the run's env itself",
    "seed": "the job's seed is used",
    "device": "the run's device is used",
    "tensorboard_log": "an outside entrant writes only into its job folder",
    "verbose": "SB3 prints nothing inside a tournament",
    "_init_setup_model": "the model is always set up",
}
"""Constructor arguments the adapter sets itself, and why a tournament file may not."""

MEMBER = "formula_tourney.json"
"""The zip member that names the library and algorithm of a saved model (SB3 ignores it)."""


def import_library(library: str) -> Any:
    """The library's module; a missing extra is one line naming how to install it."""
    module, dist = LIBRARIES[library]
    try:
        return importlib.import_module(module)
    except ImportError:
        raise UserInputError(
            f"{library} entrants need the optional extra ({dist}): {EXTRA_HINT}"
        ) from None


UNSUPPORTED: dict[str, str] = {
    "DQN": "discrete actions only",
    "QRDQN": "discrete actions only",
    "MaskablePPO": "discrete actions with masks",
    "RecurrentPPO": "carries LSTM states",
}
"""Algorithms of the libraries the adapter cannot drive, and why."""


def algorithm_class(library: str, algorithm: str) -> type:
    """The SB3 algorithm class named ``algorithm`` in ``library``; an unknown name lists the
    off- and on-policy algorithms for continuous actions the library has."""
    module = import_library(library)
    off = importlib.import_module("stable_baselines3.common.off_policy_algorithm")
    on = importlib.import_module("stable_baselines3.common.on_policy_algorithm")
    bases = (off.OffPolicyAlgorithm, on.OnPolicyAlgorithm)
    known = sorted(n for n in getattr(module, "__all__", dir(module))
                   if isinstance(getattr(module, n, None), type)
                   and issubclass(getattr(module, n), bases) and n not in UNSUPPORTED)  # fmt: skip
    if algorithm not in known:
        why = f" ({UNSUPPORTED[algorithm]})" if algorithm in UNSUPPORTED else ""
        raise ValueError(f"unknown or unsupported {library} algorithm {algorithm!r}{why}; "
                         f"allowed values: {', '.join(known)}")  # fmt: skip
    return getattr(module, algorithm)


def library_label(library: str, algorithm: str) -> str:
    """``sb3 2.9.2 SAC`` / ``sb3-contrib 2.9.2 CrossQ``: what every table calls the entrant."""
    _module, dist = LIBRARIES[library]
    try:
        version = importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        version = "?"
    return f"{library.replace('_', '-')} {version} {algorithm}"


class SB3Settings(BaseModel):
    """An SB3 entrant: which library and algorithm, and its constructor's keyword arguments."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    library: Literal["sb3", "sb3_contrib"] = Field(
        description="sb3 (stable-baselines3) or sb3_contrib (sb3-contrib)."
    )
    algorithm: str = Field(description="The algorithm's class name, e.g. SAC, TD3, PPO, CrossQ.")
    kwargs: dict[str, Any] = Field(
        default_factory=dict,
        description="Keyword arguments of the algorithm's constructor (learning_rate, "
        "buffer_size, learning_starts, policy_kwargs, ...); checked against its signature.",
    )

    @model_validator(mode="after")
    def _known(self) -> SB3Settings:
        cls = algorithm_class(self.library, self.algorithm)
        params = inspect.signature(cls.__init__).parameters
        allowed = [p for p in params if p not in ("self", "args", "kwargs") and p not in
                   OWNED_KWARGS]  # fmt: skip
        for key in self.kwargs:
            if key in OWNED_KWARGS:
                raise ValueError(f"kwargs.{key} is set by the adapter: {OWNED_KWARGS[key]}")
            if key not in allowed:
                raise ValueError(f"kwargs.{key}: not an argument of {self.algorithm}; allowed "
                                 f"keys: {', '.join(allowed)}")  # fmt: skip
        return self


def _spaces_env(spaces: EntrantSpaces) -> Any:
    """A gymnasium env that only carries the run's spaces; SB3 never steps it."""
    gym = importlib.import_module("gymnasium")

    class SpacesOnly(gym.Env):
        """The run's observation and action spaces; the loop steps the real env."""

        def __init__(self) -> None:
            self.observation_space = gym.spaces.Box(-np.inf, np.inf, (spaces.obs_dim,),
                                                    np.float32)  # fmt: skip
            low = np.asarray(spaces.action_low, np.float32)
            self.action_space = gym.spaces.Box(low, np.asarray(spaces.action_high, np.float32))

        def reset(self, *, seed: int | None = None, options: Any = None) -> Any:
            super().reset(seed=seed)
            return np.zeros(spaces.obs_dim, np.float32), {}

        def step(self, action: Any) -> Any:
            raise RuntimeError("training.loop steps the cars; SB3 never steps this env")

    return SpacesOnly


def _quiet_logger() -> Any:
    """SB3's logger with no outputs: ``train`` records its losses, nothing is written."""
    return importlib.import_module("stable_baselines3.common.logger").Logger(
        folder=None, output_formats=[])  # fmt: skip


class SB3Entrant:
    """One SB3 model behind the entrant protocol (``agents.protocol.Entrant``)."""

    window = 1

    def __init__(self, model: Any, settings: SB3Settings, spaces: EntrantSpaces) -> None:
        self.model = model
        self.settings = settings
        self.spaces = spaces
        self.label = library_label(settings.library, settings.algorithm)
        off_policy = importlib.import_module("stable_baselines3.common.off_policy_algorithm")
        self.off_policy = isinstance(model, off_policy.OffPolicyAlgorithm)
        model.set_logger(_quiet_logger())
        noise = getattr(model, "action_noise", None)
        self.noises = [copy.deepcopy(noise) for _ in range(spaces.cars)] if noise else []
        # off-policy: the rollout in progress (train_freq counts loop steps or episodes)
        self.steps_since_train = 0
        self.episodes_since_train = 0
        self.transitions_since_train = 0
        self.observed = 0  # transitions of the loop step being observed
        # on-policy: per-car queues of stored transitions and of the samples that made them
        self.pending: list[deque[Transition]] = [deque() for _ in range(spaces.cars)]
        self.samples: list[deque[tuple[np.ndarray, float, float]]] = [
            deque() for _ in range(spaces.cars)]  # fmt: skip
        self.episode_starts = np.ones(spaces.cars, dtype=bool)
        self.last_next_obs = np.zeros((spaces.cars, spaces.obs_dim), np.float32)
        self.last_dones = np.zeros(spaces.cars, dtype=bool)

    @property
    def updates(self) -> int:
        """SB3's count of gradient updates (the tables' ``updates`` column)."""
        return int(self.model._n_updates)

    # ---------------------------------------------------------------------------- protocol
    @classmethod
    def settings_model(cls) -> type[pydantic.BaseModel]:
        """The library, algorithm and constructor keywords (:class:`SB3Settings`)."""
        return SB3Settings

    @classmethod
    def build(cls, settings: pydantic.BaseModel, spaces: EntrantSpaces, seed: int,
              device: str) -> SB3Entrant:  # fmt: skip
        """The algorithm on the run's spaces, seeded with ``seed`` (SB3's own seeding)."""
        assert isinstance(settings, SB3Settings)
        algo = algorithm_class(settings.library, settings.algorithm)
        vec = importlib.import_module("stable_baselines3.common.vec_env").DummyVecEnv
        off_policy = importlib.import_module("stable_baselines3.common.off_policy_algorithm")
        lanes = 1 if issubclass(algo, off_policy.OffPolicyAlgorithm) else spaces.cars
        env = vec([_spaces_env(spaces)] * lanes)
        model = algo("MlpPolicy", env, seed=seed, device="cpu" if device == "auto" else device,
                     verbose=0, tensorboard_log=None, **settings.kwargs)  # fmt: skip
        return cls(model, settings, spaces)

    def act(self, windows: np.ndarray) -> np.ndarray:
        """SB3's deterministic ``predict`` on each car's last observation."""
        action, _ = self.model.predict(self._obs(windows), deterministic=True)
        return np.asarray(action, np.float32).reshape(len(windows), self.spaces.action_dim)

    def explore(self, windows: np.ndarray, env_steps: int) -> np.ndarray:
        """SB3's exploring action: uniform before ``learning_starts``, then its policy's sample
        (plus its action noise) for off-policy; the policy's sample, value and log-probability
        (kept for the rollout buffer) for on-policy."""
        obs = self._obs(windows)
        if not self.off_policy:
            return self._sample_on_policy(obs)
        model = self.model
        cars = len(obs)
        if model.num_timesteps < model.learning_starts and not (
            model.use_sde and model.use_sde_at_warmup
        ):
            unscaled = np.array([model.action_space.sample() for _ in range(cars)])
        else:
            unscaled, _ = model.predict(obs, deterministic=False)
        if self.noises:
            scaled = model.policy.scale_action(np.asarray(unscaled).reshape(cars, -1))
            scaled = np.stack([np.clip(scaled[c] + self.noises[c](), -1, 1) for c in range(cars)])
            unscaled = model.policy.unscale_action(scaled)
        return np.asarray(unscaled, np.float32).reshape(cars, self.spaces.action_dim)

    def observe(self, transitions: Sequence[Transition]) -> None:
        """Off-policy: each transition into the replay buffer; on-policy: a rollout row once
        every car has stored a step."""
        self.observed += len(transitions)
        if self.off_policy:
            for t in transitions:
                self._store(t)
        else:
            for t in transitions:
                self.pending[t.car].append(t)
            while all(self.pending):
                self._add_row([q.popleft() for q in self.pending])

    def update(self, env_steps: int) -> dict[str, float]:
        """Train as SB3's ``learn`` would at this point; the losses SB3 logged."""
        observed, self.observed = self.observed, 0
        if self.off_policy:
            self._train_off_policy(observed)
        elif self.model.rollout_buffer.full:
            self._train_on_policy()
        return self._losses()

    def episode_started(self, car: int) -> None:
        """Reset the car's action noise (an OU process carries over otherwise)."""
        if self.noises:
            self.noises[car].reset()
        self.episode_starts[car] = True

    def save(self, path: Path) -> None:
        """SB3's zip of the model (no replay buffer), with a member naming what to load it as."""
        buffer = io.BytesIO()
        self.model.save(buffer)
        with zipfile.ZipFile(buffer, "a") as archive:
            archive.writestr(MEMBER, json.dumps({
                "settings": self.settings.model_dump(mode="json"),
                "spaces": {"obs_dim": self.spaces.obs_dim, "action_dim": self.spaces.action_dim,
                           "action_low": self.spaces.action_low.tolist(),
                           "action_high": self.spaces.action_high.tolist(),
                           "cars": self.spaces.cars},
            }))  # fmt: skip
        atomic_write_bytes(path, buffer.getvalue())

    @classmethod
    def load(cls, path: Path, device: str) -> SB3Entrant:
        """A model ``save`` wrote, through SB3's ``load`` (which unpickles parts of the file:
        only load files a run wrote)."""
        data = Path(path).read_bytes()
        try:
            with zipfile.ZipFile(io.BytesIO(data)) as archive:
                meta = json.loads(archive.read(MEMBER))
        except (zipfile.BadZipFile, KeyError, ValueError):
            raise UserInputError(f"{path}: not a model saved by the SB3 adapter") from None
        settings = SB3Settings.model_validate(meta["settings"])
        s = meta["spaces"]
        low, high = (np.asarray(s[k], np.float32) for k in ("action_low", "action_high"))
        spaces = EntrantSpaces(int(s["obs_dim"]), int(s["action_dim"]), low, high, int(s["cars"]))
        algo = algorithm_class(settings.library, settings.algorithm)
        model = algo.load(io.BytesIO(data), device="cpu" if device == "auto" else device)
        return cls(model, settings, spaces)

    def training_state(self) -> dict[str, Any]:
        """Weights, optimisers, the buffer so far, counters and every RNG SB3 draws from."""
        model = self.model
        _dicts, variables = model._get_torch_save_params()
        np_state = np.random.get_state()
        state: dict[str, Any] = {
            "params": model.get_parameters(),
            "variables": {n: _attr(model, n).detach().clone() for n in variables},
            "num_timesteps": int(model.num_timesteps), "n_updates": int(model._n_updates),
            "counters": [self.steps_since_train, self.episodes_since_train,
                         self.transitions_since_train, self.observed],
            "episode_starts": torch.from_numpy(self.episode_starts.copy()),
            "last_next_obs": torch.from_numpy(self.last_next_obs.copy()),
            "last_dones": torch.from_numpy(self.last_dones.copy()),
            "rng": {"torch": torch.get_rng_state(), "random": random.getstate(),
                    "numpy": [np_state[0], torch.from_numpy(np_state[1].astype(np.int64)),
                              *np_state[2:]],
                    "space": json.dumps(model.action_space.np_random.bit_generator.state)},
            "noises": [_noise_state(n) for n in self.noises],
            "buffer": _buffer_state(model.replay_buffer if self.off_policy
                                    else model.rollout_buffer),
            "pending": [[_transition_state(t) for t in q] for q in self.pending],
            "samples": [[[torch.from_numpy(a), v, lp] for a, v, lp in q] for q in self.samples],
        }  # fmt: skip
        return state

    def restore_training_state(self, state: dict[str, Any]) -> None:
        """Continue from :meth:`training_state` of an entrant built with the same settings."""
        model = self.model
        model.set_parameters(state["params"], exact_match=True, device=model.device)
        for name, value in state["variables"].items():
            _attr(model, name).data.copy_(value)
        model.num_timesteps = int(state["num_timesteps"])
        model._n_updates = int(state["n_updates"])
        (self.steps_since_train, self.episodes_since_train, self.transitions_since_train,
         self.observed) = (int(x) for x in state["counters"])  # fmt: skip
        self.episode_starts = state["episode_starts"].numpy().copy()
        self.last_next_obs = state["last_next_obs"].numpy().copy()
        self.last_dones = state["last_dones"].numpy().copy()
        rng = state["rng"]
        torch.set_rng_state(rng["torch"])
        random.setstate(_tuples(rng["random"]))
        kind, keys, *rest = rng["numpy"]
        np.random.set_state((kind, keys.numpy().astype(np.uint32), *rest))
        model.action_space.np_random.bit_generator.state = json.loads(rng["space"])
        for noise, saved in zip(self.noises, state["noises"], strict=True):
            _restore_noise(noise, saved)
        _restore_buffer(model.replay_buffer if self.off_policy else model.rollout_buffer,
                        state["buffer"])  # fmt: skip
        self.pending = [deque(_transition(d) for d in q) for q in state["pending"]]
        self.samples = [deque((a.numpy(), float(v), float(lp)) for a, v, lp in q)
                        for q in state["samples"]]  # fmt: skip

    # ------------------------------------------------------------------------- internals
    def _obs(self, windows: np.ndarray) -> np.ndarray:
        """Each car's last observation step: SB3 policies read one step (``window`` 1)."""
        return np.asarray(windows, np.float32)[:, -1, :]

    def _store(self, t: Transition) -> None:
        """One transition into SB3's replay buffer as ``_store_transition`` would put it."""
        model = self.model
        scaled = np.clip(model.policy.scale_action(np.asarray(t.action, np.float32)), -1, 1)
        done = bool(t.terminated or t.truncated)
        info = {"TimeLimit.truncated": bool(t.truncated and not t.terminated)}
        reward = np.array([t.reward], np.float32)
        model.replay_buffer.add(t.obs[None], t.next_obs[None], scaled[None], reward,
                                np.array([done]), [info])  # fmt: skip
        model.num_timesteps += 1
        self.transitions_since_train += 1
        self.episodes_since_train += int(done)

    def _train_off_policy(self, observed: int) -> None:
        """``OffPolicyAlgorithm.learn``: after each ``train_freq`` (steps or episodes) and past
        ``learning_starts``, ``gradient_steps`` updates (-1: as many as transitions came)."""
        model = self.model
        if observed:
            self.steps_since_train += 1
        freq = model.train_freq
        unit = getattr(freq.unit, "value", freq.unit)
        done = (self.steps_since_train >= freq.frequency if unit == "step"
                else self.episodes_since_train >= freq.frequency)  # fmt: skip
        if not done:
            return
        collected = self.transitions_since_train
        self.steps_since_train = self.episodes_since_train = self.transitions_since_train = 0
        if model.num_timesteps > 0 and model.num_timesteps > model.learning_starts:
            steps = model.gradient_steps if model.gradient_steps >= 0 else collected
            if steps > 0:
                model.train(batch_size=model.batch_size, gradient_steps=steps)

    def _sample_on_policy(self, obs: np.ndarray) -> np.ndarray:
        """The policy's sample per car, its value and log-probability kept for the rollout."""
        model = self.model
        utils = importlib.import_module("stable_baselines3.common.utils")
        with torch.no_grad():
            actions, values, log_probs = model.policy(utils.obs_as_tensor(obs, model.device))
        actions = actions.cpu().numpy()
        for car in range(len(obs)):
            self.samples[car].append((actions[car].copy(), float(values[car]),
                                      float(log_probs[car])))  # fmt: skip
        if model.policy.squash_output:
            applied = model.policy.unscale_action(actions)
        else:
            applied = np.clip(actions, model.action_space.low, model.action_space.high)
        return np.asarray(applied, np.float32)

    def _add_row(self, row: list[Transition]) -> None:
        """One step of every car into the rollout buffer (``collect_rollouts``)."""
        model = self.model
        obs = np.stack([t.obs for t in row]).astype(np.float32)
        actions, values, log_probs = [], [], []
        for car, t in enumerate(row):
            sample = self.samples[car].popleft() if self.samples[car] else None
            if sample is None:  # the loop drove this step greedily: evaluate what it applied
                sample = self._evaluate(t)
            actions.append(sample[0])
            values.append(sample[1])
            log_probs.append(sample[2])
        rewards = np.array([t.reward for t in row], np.float32)
        for car, t in enumerate(row):
            if t.truncated and not t.terminated:  # SB3 bootstraps a time-limit cut
                with torch.no_grad():
                    value = model.policy.predict_values(model.policy.obs_to_tensor(t.next_obs)[0])
                rewards[car] += model.gamma * float(value[0])
        model.rollout_buffer.add(obs, np.stack(actions), rewards, self.episode_starts.copy(),
                                 torch.tensor(values), torch.tensor(log_probs))  # fmt: skip
        self.last_next_obs = np.stack([t.next_obs for t in row]).astype(np.float32)
        self.last_dones = np.array([t.terminated or t.truncated for t in row])
        self.episode_starts = self.last_dones.copy()
        model.num_timesteps += len(row)

    def _evaluate(self, t: Transition) -> tuple[np.ndarray, float, float]:
        """Value and log-probability of an applied action the policy did not sample here."""
        model = self.model
        action = np.asarray(t.action, np.float32)
        if model.policy.squash_output:
            action = model.policy.scale_action(action)
        obs_t = model.policy.obs_to_tensor(t.obs)[0]
        with torch.no_grad():
            values, log_prob, _ = model.policy.evaluate_actions(
                obs_t, torch.from_numpy(action)[None]
            )
        return action, float(values[0]), float(log_prob[0])

    def _train_on_policy(self) -> None:
        """The full rollout's returns and advantages, then SB3's ``train``."""
        model = self.model
        utils = importlib.import_module("stable_baselines3.common.utils")
        with torch.no_grad():
            values = model.policy.predict_values(utils.obs_as_tensor(self.last_next_obs,
                                                                     model.device))  # fmt: skip
        model.rollout_buffer.compute_returns_and_advantage(last_values=values,
                                                           dones=self.last_dones)  # fmt: skip
        model.train()
        model.policy.set_training_mode(False)
        model.rollout_buffer.reset()

    def _losses(self) -> dict[str, float]:
        """The losses SB3's ``train`` logged since the last call (then forgotten)."""
        values = self.model.logger.name_to_value
        out = {k.removeprefix("train/"): float(v) for k, v in values.items()
               if k.startswith("train/") and "loss" in k
               and isinstance(v, (int, float))}  # fmt: skip
        values.clear()
        return out


def _attr(obj: Any, dotted: str) -> Any:
    for name in dotted.split("."):
        obj = getattr(obj, name)
    return obj


def _tuples(value: Any) -> Any:
    """Lists back to tuples (``random.setstate`` wants its state's own types)."""
    return tuple(_tuples(v) for v in value) if isinstance(value, (list, tuple)) else value


_BUFFER_ARRAYS = (
    "observations",
    "next_observations",
    "actions",
    "rewards",
    "dones",
    "timeouts",
    "episode_starts",
    "values",
    "log_probs",
    "advantages",
    "returns",
)
"""The array attributes of SB3's replay and rollout buffers (each has some of them)."""


def _buffer_state(buffer: Any) -> dict[str, Any]:
    """The filled rows of a replay or rollout buffer, as tensors."""
    rows = buffer.buffer_size if buffer.full else buffer.pos
    names = [n for n in _BUFFER_ARRAYS if isinstance(getattr(buffer, n, None), np.ndarray)]
    arrays = {n: torch.from_numpy(np.ascontiguousarray(getattr(buffer, n)[:rows])) for n in names}
    return {"pos": int(buffer.pos), "full": bool(buffer.full), "rows": rows, "arrays": arrays}


def _restore_buffer(buffer: Any, state: dict[str, Any]) -> None:
    rows = int(state["rows"])
    for name, value in state["arrays"].items():
        getattr(buffer, name)[:rows] = value.numpy()
    buffer.pos = int(state["pos"])
    buffer.full = bool(state["full"])


def _noise_state(noise: Any) -> dict[str, Any]:
    """An SB3 action noise's running state (OU keeps its previous value)."""
    prev = getattr(noise, "noise_prev", None)
    return {"noise_prev": None if prev is None else torch.from_numpy(np.array(prev))}


def _restore_noise(noise: Any, state: dict[str, Any]) -> None:
    if state["noise_prev"] is not None:
        noise.noise_prev = state["noise_prev"].numpy().copy()


def _transition_state(t: Transition) -> list[Any]:
    return [t.car, torch.from_numpy(np.asarray(t.obs)), torch.from_numpy(np.asarray(t.action)),
            float(t.reward), torch.from_numpy(np.asarray(t.next_obs)), bool(t.terminated),
            bool(t.truncated)]  # fmt: skip


def _transition(data: list[Any]) -> Transition:
    car, obs, action, reward, next_obs, terminated, truncated = data
    return Transition(int(car), obs.numpy(), action.numpy(), float(reward), next_obs.numpy(),
                      bool(terminated), bool(truncated))  # fmt: skip
