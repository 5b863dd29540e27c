"""LayerNorm critics (beyond the paper): a setting of DDPG, TD3 and SAC, refused where it cannot
apply, off by default with the paper's critic parameter for parameter."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from formula_tourney.agents.buffers import ReplayBuffer
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.variants import get_variant
from formula_tourney.errors import UserInputError

torch.set_num_threads(1)
D = 4


def _batch(seed: int = 0):  # type: ignore[no-untyped-def]
    buf = ReplayBuffer(1000, D, 3, seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(50):
        buf.add(rng.normal(size=D), rng.random(3), rng.normal(), rng.normal(size=D),
                terminated=False, truncated=False)  # fmt: skip
    return buf.sample(16)


def test_a_layer_norm_critic_is_blind_to_the_scale_of_its_first_layer() -> None:
    """LayerNorm's defining property: scaling W1 and b1 by c > 0 leaves Q unchanged (the plain
    critic's Q scales with it)."""
    for norm in (True, False):
        agent = make_agent(get_variant("WIN1", {"hidden": (16, 12), "critic_layer_norm": norm}),
                           D, seed=1)  # fmt: skip
        obs, act = torch.randn(8, 1, D), torch.rand(8, 3)
        with torch.no_grad():
            q = agent.critic(obs, act)
            agent.critic.l1.weight.mul_(7.0)
            agent.critic.l1.bias.mul_(7.0)
            q_scaled = agent.critic(obs, act)
        assert torch.allclose(q, q_scaled, atol=1e-5) is norm


@pytest.mark.parametrize("variant", ["WIN1", "TD3", "SAC"])
def test_each_mlp_family_trains_with_layer_norm_critics(variant: str) -> None:
    agent = make_agent(get_variant(variant, {"hidden": (16, 12), "critic_layer_norm": True}), D,
                       seed=0)  # fmt: skip
    names = [n for n, _ in agent.critic.named_parameters()]
    assert sum("norm1" in n or "norm2" in n for n in names) == (4 if variant == "WIN1" else 8)
    assert agent._mlp_update is None  # DDPG's hand-written backend has no norm: autograd
    before = agent.critic.state_dict()["norm2.weight" if variant == "WIN1" else "q1.norm2.weight"]
    before = before.clone()
    for seed in range(4):
        assert all(np.isfinite(v) for v in agent.update(_batch(seed)))
    after = agent.critic.state_dict()["norm2.weight" if variant == "WIN1" else "q1.norm2.weight"]
    assert not torch.equal(before, after)  # the norms' gains learn


def test_off_by_default_the_critic_has_the_papers_parameters() -> None:
    agent = make_agent(get_variant("WIN1", {"hidden": (16, 12)}), D, seed=0)
    assert not any("norm" in n for n in agent.critic.state_dict())
    assert agent._mlp_update is not None


@pytest.mark.parametrize(("variant", "what"), [("LSTM4", "lstm_critic"), ("CrossQ", "crossq")])
def test_layer_norm_is_refused_where_the_critic_is_not_an_mlp(variant: str, what: str) -> None:
    with pytest.raises(UserInputError, match=f"critic_layer_norm applies to the MLP.*not {what}"):
        get_variant(variant, {"critic_layer_norm": True})
