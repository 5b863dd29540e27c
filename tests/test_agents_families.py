"""The family registry: a new family is one class and one registry entry, unknown names are clear
errors, and each family's own settings are refused on every other family."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from pydantic.fields import FieldInfo

from formula_tourney.agents.buffers import ReplayBuffer
from formula_tourney.agents.checkpoints import load_checkpoint, save_checkpoint
from formula_tourney.agents.core import Agent, FamilySettings
from formula_tourney.agents.crossq import CrossQAgent
from formula_tourney.agents.ddpg import DDPGAgent
from formula_tourney.agents.families import ALGORITHMS, get_family, make_agent
from formula_tourney.agents.networks import MLPCritic
from formula_tourney.agents.sac import SACAgent
from formula_tourney.agents.td3 import TD3Agent
from formula_tourney.agents.variants import ALL_VARIANTS, AgentConfig, SharedSettings, get_variant
from formula_tourney.errors import UserInputError

torch.set_num_threads(1)
D = 4


class BanditAgent(Agent):
    """A toy family: every step its own episode, so y = r; the actor ascends Q as DDPG's does."""

    algorithm = "bandit"
    tourney_families = ("BANDIT",)
    settings = FamilySettings
    checkpoint_keys = ("actor_target",)

    def _make_critic(self) -> torch.nn.Module:
        return MLPCritic(self.obs_dim, self.action_dim, self.cfg.window, self.cfg.hidden)

    @torch.no_grad()
    def target(self, rewards, discounts, next_observations, next_action_windows):  # type: ignore[no-untyped-def]
        return rewards.clone()

    def critic_objective(self, critic_loss: torch.Tensor) -> torch.Tensor:
        return critic_loss

    def actor_loss(self, q_pi: torch.Tensor, log_pi: torch.Tensor | None) -> torch.Tensor:
        return -q_pi.mean()


@pytest.fixture
def bandit(monkeypatch: pytest.MonkeyPatch) -> AgentConfig:
    """The toy family registered for one test, and a config of it."""
    monkeypatch.setitem(ALGORITHMS, "bandit", BanditAgent)
    return AgentConfig(name="B1", family="BANDIT", algorithm="bandit", hidden=(16, 12),
                       batch_size=8, buffer_size=1000)  # fmt: skip


def _batch(seed: int = 0):  # type: ignore[no-untyped-def]
    buf = ReplayBuffer(1000, D, 3, seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(50):
        buf.add(rng.normal(size=D), rng.random(3), rng.normal(), rng.normal(size=D),
                terminated=False, truncated=False)  # fmt: skip
    return buf.sample(8)


def test_the_registry_names_the_four_families_in_order() -> None:
    assert {
        "ddpg": DDPGAgent, "td3": TD3Agent, "sac": SACAgent, "crossq": CrossQAgent
    } == ALGORITHMS
    for name, variant in ALL_VARIANTS.items():
        assert (
            type(make_agent(variant.model_copy(update={"hidden": (8, 8)}), D))
            is ALGORITHMS[variant.algorithm]
        ), name


def test_a_family_registered_by_name_trains_and_round_trips(bandit, tmp_path: Path) -> None:
    agent = make_agent(bandit, D, seed=0)
    assert type(agent) is BanditAgent and agent._mlp_update is None  # DDPG's backend is DDPG's
    batch = _batch()
    t = agent._tensors(batch)
    with torch.no_grad():
        q = agent.critic(t["observations"], t["actions"]).view(-1)
    expected = float(((t["rewards"] - q) ** 2).mean())  # y = r: the toy's own target
    info = agent.update(batch)
    assert info.critic_loss == pytest.approx(expected, rel=1e-6)
    assert info.q_mean == pytest.approx(float(q.mean()), rel=1e-6)
    path = save_checkpoint(agent, tmp_path / "b.pt", extra={"episode": 1})
    loaded, extra = load_checkpoint(path)
    assert type(loaded) is BanditAgent and loaded.cfg == bandit and extra == {"episode": 1}
    window = np.ones((1, D), np.float32)
    np.testing.assert_array_equal(agent.act(window), loaded.act(window))
    batch = _batch(1)
    assert agent.update(batch) == loaded.update(batch)


def test_an_unknown_family_is_a_clear_error(tmp_path: Path) -> None:
    known = r"unknown algorithm 'ppo'; known: ddpg, td3, sac, crossq"
    with pytest.raises(UserInputError, match=known):
        get_family("ppo")
    with pytest.raises(ValueError, match=known):
        AgentConfig(algorithm="ppo")
    state = DDPGAgent(get_variant("WIN1", {"hidden": (8, 8)}), D, seed=0).state_dict()
    state["config"]["algorithm"] = "ppo"
    torch.save(state, tmp_path / "ppo.pt")
    with pytest.raises(UserInputError, match=r"ppo.pt has a bad agent config.*unknown algorithm"):
        load_checkpoint(tmp_path / "ppo.pt")


def test_a_family_class_refuses_another_familys_config() -> None:
    with pytest.raises(UserInputError, match="DDPGAgent runs algorithm ddpg, not td3"):
        DDPGAgent(get_variant("TD3", {"hidden": (8, 8)}), D)


def _off_default(field: FieldInfo) -> object:
    """A valid value of ``field`` other than its default."""
    default = field.default
    if isinstance(default, bool):
        return not default
    if default is None:
        return -1.0
    if isinstance(default, tuple):  # a pair of bounds
        return tuple(v * 0.5 for v in default)
    if isinstance(default, int) and default == 0:  # a count that is off by default
        return 2
    if default == 0.0:  # a weight that is off by default
        return 1.0
    return default + 1 if isinstance(default, int) else default * 0.5


OWN_SETTINGS = [
    (family.algorithm, key)
    for family in ALGORITHMS.values()
    for key in family.settings.model_fields
]


@pytest.mark.parametrize(("algorithm", "key"), OWN_SETTINGS)
def test_a_familys_settings_are_its_own(algorithm: str, key: str) -> None:
    """Set by the same flat key on a variant of its family, refused on every other family's."""
    value = _off_default(ALGORITHMS[algorithm].settings.model_fields[key])
    for name, variant in ALL_VARIANTS.items():
        if key == "critic_bins" and variant.lstm_critic:  # the MLP critic's alone
            with pytest.raises(UserInputError, match="not lstm_critic"):
                get_variant(name, {key: value})
        elif (key in ("critic_sigma_start_bins", "critic_sigma_warmup_updates")
              and variant.algorithm == algorithm):  # the target's warm-up: both or neither
            with pytest.raises(UserInputError, match="both or neither"):
                get_variant(name, {key: value})
        elif (key in ("critic_value_range", "critic_sigma_bins", "critic_mse_weight")
              and variant.algorithm == algorithm):
            # the bins' span, their target's spread and the squared error beside it
            with pytest.raises(UserInputError, match="needs critic_bins"):
                get_variant(name, {key: value})
            if not variant.lstm_critic:
                assert getattr(get_variant(name, {key: value, "critic_bins": 2}), key) == value
        elif variant.algorithm == algorithm:
            assert getattr(get_variant(name, {key: value}), key) == value
        else:
            message = f"{key} apply to algorithm {algorithm} only, not {variant.algorithm}"
            with pytest.raises(UserInputError, match=message):
                get_variant(name, {key: value})


def test_each_setting_is_declared_once() -> None:
    """The shared settings and every family's own are disjoint, and AgentConfig is their union."""
    own = [k for family in ALGORITHMS.values() for k in family.settings.model_fields]
    assert len(own) == len(set(own)) == 20
    assert not set(own) & set(SharedSettings.model_fields)
    assert set(AgentConfig.model_fields) == set(SharedSettings.model_fields) | set(own)
    assert all(AgentConfig.model_fields[k].description for k in AgentConfig.model_fields)
