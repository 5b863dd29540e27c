"""A single-file SAC driver for formula-tourney: the entrant protocol, written from scratch.

Race it in a tournament with ``impl = "examples.tiny_sac:TinySAC"`` (run from the repository
root, so ``examples`` is importable). Everything it learns with lives here: a replay buffer of
numpy arrays, a squashed Gaussian actor, twin critics with Polyak-averaged targets and a learned
temperature (Haarnoja et al. 2018). The loop steps the cars and hands over the transitions; this
class never sees an env or a track.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import nn

from formula_tourney.agents.protocol import EntrantSpaces, Transition
from formula_tourney.safeio import atomic_write


class TinySACSettings(BaseModel):
    """What a tournament file may set for TinySAC."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    hidden: int = Field(64, ge=4, le=1024, description="Units of each hidden layer.")
    lr: float = Field(1e-3, gt=0, le=1, description="Adam learning rate of every network.")
    gamma: float = Field(0.99, gt=0, le=1, description="Discount.")
    tau: float = Field(0.01, gt=0, le=1, description="Polyak rate of the target critics.")
    batch_size: int = Field(64, ge=1, le=4096, description="Transitions per update.")
    buffer_size: int = Field(50_000, ge=100, le=2_000_000, description="Replay capacity.")
    learning_starts: int = Field(200, ge=0, description="Uniform random actions before this.")


def mlp(inp: int, out: int, hidden: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inp, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                         nn.Linear(hidden, out))  # fmt: skip


class Actor(nn.Module):
    """Squashed Gaussian policy, rescaled to the env's action bounds."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int, low: Any, high: Any) -> None:
        super().__init__()
        self.net = mlp(obs_dim, 2 * act_dim, hidden)
        self.register_buffer("scale", torch.as_tensor((high - low) / 2, dtype=torch.float32))
        self.register_buffer("bias", torch.as_tensor((high + low) / 2, dtype=torch.float32))

    def forward(self, obs: torch.Tensor, greedy: bool = False) -> tuple[torch.Tensor, Any]:
        mean, log_std = self.net(obs).chunk(2, dim=-1)
        if greedy:
            return torch.tanh(mean) * self.scale + self.bias, None
        std = log_std.clamp(-5, 2).exp()
        u = mean + std * torch.randn_like(mean)
        a = torch.tanh(u)
        logp = torch.distributions.Normal(mean, std).log_prob(u).sum(-1)
        logp = logp - torch.log(self.scale * (1 - a.pow(2)) + 1e-6).sum(-1)
        return a * self.scale + self.bias, logp


class TinySAC:
    """SAC behind ``formula_tourney.agents.protocol.Entrant``; one update per stored step."""

    window = 1

    def __init__(self, s: TinySACSettings, spaces: EntrantSpaces, seed: int) -> None:
        self.s, self.spaces = s, spaces
        self.label = "TinySAC (examples/tiny_sac.py)"
        torch.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        o, a, h = spaces.obs_dim, spaces.action_dim, s.hidden
        self.actor = Actor(o, a, h, spaces.action_low, spaces.action_high)
        self.q = nn.ModuleList([mlp(o + a, 1, h), mlp(o + a, 1, h)])
        self.q_target = nn.ModuleList([mlp(o + a, 1, h), mlp(o + a, 1, h)])
        self.q_target.load_state_dict(self.q.state_dict())
        self.log_alpha = torch.zeros(1, requires_grad=True)
        self.opt_actor = torch.optim.Adam(self.actor.parameters(), lr=s.lr)
        self.opt_q = torch.optim.Adam(self.q.parameters(), lr=s.lr)
        self.opt_alpha = torch.optim.Adam([self.log_alpha], lr=s.lr)
        self.buf = {k: np.zeros((s.buffer_size, n), np.float32) for k, n in
                    (("obs", o), ("act", a), ("rew", 1), ("next", o), ("done", 1))}  # fmt: skip
        self.size = self.pos = self.stored = self.updates = 0

    @classmethod
    def settings_model(cls) -> type[BaseModel]:
        return TinySACSettings

    @classmethod
    def build(cls, settings: BaseModel, spaces: EntrantSpaces, seed: int, device: str) -> TinySAC:
        return cls(TinySACSettings.model_validate(settings.model_dump()), spaces, seed)

    def act(self, windows: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.actor(torch.as_tensor(windows[:, -1]), greedy=True)[0].numpy()

    def explore(self, windows: np.ndarray, env_steps: int) -> np.ndarray:
        if self.stored < self.s.learning_starts:
            low, high = self.spaces.action_low, self.spaces.action_high
            return self.rng.uniform(low, high, (len(windows), len(low))).astype(np.float32)
        with torch.no_grad():
            return self.actor(torch.as_tensor(windows[:, -1]))[0].numpy()

    def observe(self, transitions: Sequence[Transition]) -> None:
        for t in transitions:  # a time-limit cut bootstraps; a terminal state does not
            row = {"obs": t.obs, "act": t.action, "rew": t.reward, "next": t.next_obs,
                   "done": float(t.terminated)}  # fmt: skip
            for key, value in row.items():
                self.buf[key][self.pos] = value
            self.pos = (self.pos + 1) % self.s.buffer_size
            self.size = min(self.size + 1, self.s.buffer_size)
            self.stored += 1

    def update(self, env_steps: int) -> dict[str, float]:
        if self.stored < self.s.learning_starts or self.size < self.s.batch_size:
            return {}
        idx = self.rng.integers(0, self.size, self.s.batch_size)
        obs, act, rew, nxt, done = (torch.as_tensor(self.buf[k][idx])
                                    for k in ("obs", "act", "rew", "next", "done"))  # fmt: skip
        alpha = self.log_alpha.exp().detach()
        with torch.no_grad():
            a2, logp2 = self.actor(nxt)
            q2 = torch.min(*(q(torch.cat([nxt, a2], -1)) for q in self.q_target))
            target = rew + self.s.gamma * (1 - done) * (q2 - alpha * logp2[:, None])
        q_loss = sum(((q(torch.cat([obs, act], -1)) - target) ** 2).mean() for q in self.q)
        self.opt_q.zero_grad()
        q_loss.backward()
        self.opt_q.step()
        a, logp = self.actor(obs)
        q_pi = torch.min(*(q(torch.cat([obs, a], -1)) for q in self.q))
        actor_loss = (alpha * logp[:, None] - q_pi).mean()
        self.opt_actor.zero_grad()
        actor_loss.backward()
        self.opt_actor.step()
        alpha_loss = -(self.log_alpha * (logp.detach() - self.spaces.action_dim)).mean()
        self.opt_alpha.zero_grad()
        alpha_loss.backward()
        self.opt_alpha.step()
        with torch.no_grad():
            for p, pt in zip(self.q.parameters(), self.q_target.parameters(), strict=True):
                pt.mul_(1 - self.s.tau).add_(self.s.tau * p)
        self.updates += 1
        return {"critic": q_loss.item(), "actor": actor_loss.item(), "alpha": alpha_loss.item()}

    def episode_started(self, car: int) -> None:
        """SAC explores by sampling its policy: no per-car noise to reset."""

    def save(self, path: Path) -> None:
        data = {
            "settings": self.s.model_dump(),
            "actor": self.actor.state_dict(),
            "spaces": [
                self.spaces.obs_dim,
                self.spaces.action_dim,
                self.spaces.action_low.tolist(),
                self.spaces.action_high.tolist(),
            ],
        }
        atomic_write(path, lambda tmp: torch.save(data, tmp))

    @classmethod
    def load(cls, path: Path, device: str) -> TinySAC:
        data = torch.load(path, weights_only=True)
        o, a, low, high = data["spaces"]
        spaces = EntrantSpaces(o, a, np.asarray(low, np.float32), np.asarray(high, np.float32), 1)
        agent = cls(TinySACSettings(**data["settings"]), spaces, 0)
        agent.actor.load_state_dict(data["actor"])
        return agent

    def training_state(self) -> dict[str, Any]:
        nets = ("actor", "q", "q_target", "opt_actor", "opt_q", "opt_alpha")
        return {**{n: getattr(self, n).state_dict() for n in nets},
                "log_alpha": self.log_alpha.detach().clone(),
                "buf": {k: torch.from_numpy(v[: self.size].copy()) for k, v in self.buf.items()},
                "counters": [self.size, self.pos, self.stored, self.updates],
                "torch_rng": torch.get_rng_state(),
                "np_rng": json.dumps(self.rng.bit_generator.state)}  # fmt: skip

    def restore_training_state(self, state: dict[str, Any]) -> None:
        for n in ("actor", "q", "q_target", "opt_actor", "opt_q", "opt_alpha"):
            getattr(self, n).load_state_dict(state[n])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.size, self.pos, self.stored, self.updates = state["counters"]
        for k, v in state["buf"].items():
            self.buf[k][: self.size] = v.numpy()
        torch.set_rng_state(state["torch_rng"])
        self.rng.bit_generator.state = json.loads(state["np_rng"])
