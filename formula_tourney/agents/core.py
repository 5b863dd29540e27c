"""What every algorithm family shares: flat weights, Adam, the update skeleton, acting, state.

A family (``ddpg.py``, ``td3.py``, ``sac.py``) is a subclass of :class:`Agent` that supplies its
networks, its target, its critic and actor losses and its own settings (a :class:`FamilySettings`
model); ``families.py`` registers it by name. The skeleton of one update is the same for all:

    sample a batch (uniform or PER, n-step sums and discounts, windows: ``buffers.py``)
    y        = family.target(r^(n), d, s', past actions of s')               the target
    td       = y - Q(s, a);  L(Q) = 1/N sum_i w_i td_i^2                      w_i = 1 unless PER
             (or the family's critic_loss: DDPG's classification critic's cross-entropy)
    critic   descends family.critic_objective(L(Q))
    actor    descends family.actor_loss(Q(s, pi(s))) + the cloning term (demonstrations)
    soft     theta' <- tau theta + (1 - tau) theta'                           one lerp, flat
    PER      p_i = td_i^2 + lambda3 |grad_a Q_1(s_i, a_i)|^2 + eps

Both losses are taken at the same critic parameters (as OpenAI Baselines' DDPG), every gradient
before any step. A family may step its actor (and targets) only every ``policy_delay``-th update
(TD3). Variants are configuration: the window ``w`` is in the observation tensors' shape, the
LSTM critic is a different critic module fed the window's past actions, n-step arrives as the
batch's summed rewards and discounts, PER as weights plus a priority update.

Where a family allows it (``mlp_backend``: DDPG) and its actor is
:class:`~formula_tourney.agents.networks.Actor` and its critic
:class:`~formula_tourney.agents.networks.MLPCritic`, the update runs through the hand-written
backend (``mlp_update.py``) instead of autograd; the autograd skeleton stays the reference it is
tested against.
"""

from __future__ import annotations

import contextlib
import copy
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict
from torch import nn

from formula_tourney.agents.buffers import ReplayBatch
from formula_tourney.agents.mlp_update import BCLoss, MLPUpdate, Saturation
from formula_tourney.agents.networks import Actor, GreedyAct, MLPCritic
from formula_tourney.agents.noise import action_box
from formula_tourney.agents.obs_norm import RunningObsNorm
from formula_tourney.errors import UserInputError


class UpdateInfo(NamedTuple):
    """Scalars of one update, for TensorBoard and the NaN guard."""

    critic_loss: float
    actor_loss: float
    q_mean: float
    td_abs_mean: float


class FusedAdam:
    """Adam (Kingma & Ba) over one flat parameter tensor: the step counter, then PyTorch's fused
    kernel on one tensor per argument.

    Same arithmetic as ``torch.optim.Adam(fused=True)``; calling the kernel directly skips the
    Optimizer wrapper's Python bookkeeping (~0.26 ms per call here, ~5% of a 400-300 DDPG update
    on one CPU thread). ``params`` are views laid out consecutively in ``flat`` and ``flat_grad``
    holds their gradients in the same layout (the agent binds each parameter's ``.grad`` to its
    view, so the autograd and the hand-written update fill the same buffer). The moments are
    flat too; per-parameter views of them and of the one shared step counter form the
    checkpoint's state.
    """

    def __init__(
        self,
        params: list[torch.Tensor],
        flat: torch.Tensor,
        flat_grad: torch.Tensor,
        lr: float,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        if not _is_laid_out_in(params, flat) or flat_grad.shape != flat.shape:
            raise ValueError("FusedAdam: flat must hold exactly the parameters, in order")
        self.lr, self.betas, self.eps = lr, betas, eps
        exp_avg, exp_avg_sq = torch.zeros_like(flat), torch.zeros_like(flat)
        step_count = torch.zeros((), dtype=torch.float32, device=flat.device)
        self._kernel_args = ([flat], [flat_grad], [exp_avg], [exp_avg_sq], [], [step_count])
        self.exp_avg = _split_like(exp_avg, params)
        self.exp_avg_sq = _split_like(exp_avg_sq, params)
        self.steps = [step_count] * len(params)

    @torch.no_grad()
    def step(self) -> None:
        """One Adam step from the gradient buffer."""
        self.steps[0].add_(1.0)
        torch._fused_adam_(
            *self._kernel_args, lr=self.lr, beta1=self.betas[0], beta2=self.betas[1],
            weight_decay=0.0, eps=self.eps, amsgrad=False, maximize=False,
        )  # fmt: skip

    def state_dict(self) -> dict[str, Any]:
        return {"exp_avg": self.exp_avg, "exp_avg_sq": self.exp_avg_sq, "steps": self.steps}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        with torch.no_grad():
            for dst, src in zip(
                self.exp_avg + self.exp_avg_sq + self.steps,
                state["exp_avg"] + state["exp_avg_sq"] + state["steps"],
                strict=True,
            ):
                dst.copy_(src)


def _split_like(flat: torch.Tensor, params: list[torch.Tensor]) -> list[torch.Tensor]:
    """Consecutive views of ``flat`` shaped like ``params``."""
    views, offset = [], 0
    for p in params:
        views.append(flat[offset : offset + p.numel()].view_as(p))
        offset += p.numel()
    return views


def _is_laid_out_in(params: list[torch.Tensor], flat: torch.Tensor) -> bool:
    """True when ``params`` are consecutive views of ``flat`` that cover it exactly."""
    offset = flat.storage_offset()
    same = flat.untyped_storage().data_ptr()
    for p in params:
        if p.untyped_storage().data_ptr() != same or p.storage_offset() != offset:
            return False
        offset += p.numel()
    return offset == flat.storage_offset() + flat.numel() and flat.is_contiguous()


def _flat_views(modules: list[nn.Module]) -> torch.Tensor:
    """Move the modules' parameters into one contiguous tensor and rebind them as views of it.

    The soft target update then is one lerp over ~270k floats instead of one per tensor.
    """
    params = [p for m in modules for p in m.parameters()]
    flat = torch.cat([p.detach().reshape(-1) for p in params])
    offset = 0
    for p in params:
        n = p.numel()
        p.data = flat[offset : offset + n].view_as(p)
        offset += n
    return flat


def configure_torch(threads: int = 1) -> None:
    """Per-process torch settings of a learner: its thread count, and denormals flushed to zero.

    One place for what training, tournament workers and benchmarks set. Adam's second moments
    decay geometrically where a weight's gradient stays zero (dead ReLU units), and float32
    denormals (below 1.2e-38) run in microcode on x86; flushing them is a guard for long runs.
    At benchmark scale it changes nothing measurable (``learner_throughput.py`` times the update
    with denormals kept beside it). Values change only below 1.2e-38 and identically on every
    run, so determinism is kept. ``set_num_threads`` raises once parallel work has started in
    this process; then the current count is kept.
    """
    torch.set_flush_denormal(True)
    with contextlib.suppress(RuntimeError):
        torch.set_num_threads(int(threads))


def resolve_device(device: str) -> torch.device:
    """``auto``: CUDA when present at run time, else CPU; ``cuda`` without a GPU is an error."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise UserInputError("device 'cuda' requested but torch sees no CUDA device; use auto")
    return torch.device(device)


class FamilySettings(BaseModel):
    """Base of a family's own settings: fields that only its update reads.

    ``variants.AgentConfig`` joins every registered family's settings model into its flat keys,
    and refuses a family's field set off its default on a variant of another family.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)


class Agent:
    """Actor, critic, their targets and optimizers; ``update`` is the whole learning rule.

    Subclasses are the algorithm families. Their class attributes say what the skeleton builds:
    ``has_target_actor`` (SAC bootstraps from its current policy instead), ``uses_generator``
    (an own random stream for target noise or policy samples, seeded by the agent's seed, so
    checkpoints and copies carry it), ``twin_critics`` (Q is ``(2, B)``, row 0 is Q_1).
    """

    algorithm: ClassVar[str]
    """The name the family is registered under (the ``algorithm`` setting)."""
    tourney_families: ClassVar[tuple[str, ...]]
    """The ``family`` values its variants may carry (what tournaments promote the best of)."""
    settings: ClassVar[type[FamilySettings]]
    """The family's own settings model."""
    beyond_paper: ClassVar[bool] = True
    """Whether tables label its runs beyond the paper."""
    uses_action_noise: ClassVar[bool] = True
    """Whether the training loop adds the OU + brake exploration noise to ``explore``'s action."""
    twin_critics: ClassVar[bool] = False
    has_target_actor: ClassVar[bool] = True
    uses_generator: ClassVar[bool] = False
    checkpoint_keys: ClassVar[tuple[str, ...]] = ()
    """Checkpoint keys beyond :data:`CHECKPOINT_KEYS` that this family's ``state_dict`` writes."""
    critic_layer_norm_applies: ClassVar[bool] = True
    """Whether the setting ``critic_layer_norm`` reaches this family's critics (its MLP critics
    take it; a family with other critics says False and the setting is refused on it)."""
    mlp_backend: ClassVar[bool] = False
    """Whether the hand-written backend (``mlp_update.py``, DDPG's equations) may run this
    family's update when its networks are the MLP actor and critic."""
    moves_targets: ClassVar[bool] = True
    """Whether an actor step moves target networks toward the online ones (Polyak); a family
    whose target comes from the online critic (CrossQ) says False."""

    def __init__(
        self,
        cfg: Any,
        obs_dim: int,
        action_dim: int = 3,
        device: str = "cpu",
        seed: int | None = None,
    ) -> None:
        """``cfg`` is a ``variants.AgentConfig`` whose ``algorithm`` is this family's."""
        if cfg.algorithm != self.algorithm:
            raise UserInputError(
                f"{type(self).__name__} runs algorithm {self.algorithm}, not {cfg.algorithm}"
            )
        if seed is not None:  # initial weights depend on the seed alone
            torch.manual_seed(seed)
        self.cfg = cfg
        self.obs_dim = int(obs_dim)
        self.action_dim = int(action_dim)
        self.device = resolve_device(device)
        # cfg.obs_norm: every input of actor and critics passes the running statistics' map
        self.obs_norm = RunningObsNorm(self.obs_dim, self.device) if cfg.obs_norm else None
        self.actor_window = self._actor_window()
        self.actor: nn.Module = self._make_actor().to(self.device)
        self.critic: nn.Module = self._make_critic().to(self.device)
        self.actor_target: nn.Module | None = None
        if self.has_target_actor:
            self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        # what tests drive (cfg.eval_ema_updates): an average of the online actor's weights, which
        # the gradient steps never touch
        self.actor_eval: nn.Module | None = None
        if cfg.eval_ema_updates > 0:
            self.actor_eval = copy.deepcopy(self.actor).requires_grad_(False)
        self._online_flat = _flat_views([self.actor, self.critic])
        self._eval_flat = None if self.actor_eval is None else _flat_views([self.actor_eval])
        targets = [m for m in (self.actor_target, self.critic_target) if m is not None]
        self._target_flat = _flat_views(targets)
        self._actor_params = list(self.actor.parameters())
        self._critic_params = list(self.critic.parameters())
        # one gradient buffer laid out like the online weights, bound as every parameter's .grad:
        # autograd accumulates into it, the hand-written update writes it, Adam reads it
        self._grad_flat = torch.zeros_like(self._online_flat)
        online = self._actor_params + self._critic_params
        for p, g in zip(online, _split_like(self._grad_flat, online), strict=True):
            p.grad = g
        n_actor = sum(p.numel() for p in self._actor_params)
        self._actor_flat = self._online_flat[:n_actor]  # what the tests' average follows
        self.actor_opt = FusedAdam(
            self._actor_params, self._actor_flat, self._grad_flat[:n_actor],
            lr=cfg.actor_lr,
        )  # fmt: skip
        self.critic_opt = FusedAdam(
            self._critic_params, self._online_flat[n_actor:], self._grad_flat[n_actor:],
            lr=cfg.critic_lr,
        )  # fmt: skip
        # what the soft update moves the targets towards: all online weights, or (no target
        # actor) the critic's alone
        self._target_source = self._online_flat
        if self.actor_target is None:
            self._target_source = self._online_flat[n_actor:]
        self._policy_delay = 1  # the actor and the targets step every this many updates
        self._last_actor_loss = 0.0  # reported on critic-only updates
        self._generator: torch.Generator | None = None
        if self.uses_generator:
            self._generator = torch.Generator(device=self.device)
            self._generator.manual_seed(
                seed if seed is not None else int(torch.randint(2**62, ()).item())
            )
        low, high = action_box(self.action_dim)  # the env's box: paper or pedal action mode
        self._action_low = torch.as_tensor(low, device=self.device)
        self._action_high = torch.as_tensor(high, device=self.device)
        # the hand-written backend covers DDPG's update of the deterministic actor with the MLP
        # critic; every other family and pair of networks updates through autograd
        self._mlp_update: MLPUpdate | None = None
        mlp_nets = (isinstance(self.critic, MLPCritic) and not self.critic.layer_norm
                    and isinstance(self.actor, Actor))  # fmt: skip
        if self.mlp_backend and mlp_nets:
            assert self.actor_target is not None
            self._mlp_update = MLPUpdate(
                self.actor, self.critic, self.actor_target, self.critic_target,
                Saturation(cfg.preact_penalty, *cfg.preact_bound), cfg.critic_mse_weight,
            )
        self._greedy = GreedyAct(self.actor) if isinstance(self.actor, Actor) else None
        # what tests and races drive: the average where one is kept, else the online actor
        self._eval_actor = self.actor if self.actor_eval is None else self.actor_eval
        self._greedy_eval = (
            self._greedy if self.actor_eval is None
            else GreedyAct(self.actor_eval) if isinstance(self.actor_eval, Actor) else None
        )  # fmt: skip
        self._eval_rate = 1.0 / cfg.eval_ema_updates if cfg.eval_ema_updates else 0.0
        self.updates = 0
        self.last_priorities: np.ndarray | None = None

    def __deepcopy__(self, memo: dict[int, Any]) -> Agent:
        """A rebuilt agent with copied state: a field-by-field copy would give the networks
        separate tensors instead of views of the flat weights, and the soft update and Adam's
        flat step would then silently miss them."""
        with torch.random.fork_rng(devices=[]):  # the fresh init must not move the global RNG
            clone = type(self)(self.cfg, self.obs_dim, self.action_dim, device=str(self.device))
        clone.load_state_dict(self.state_dict())
        clone.last_priorities = copy.deepcopy(self.last_priorities, memo)
        clone._last_actor_loss = self._last_actor_loss
        return clone

    # --- what a family supplies -----------------------------------------------------------------
    def _actor_window(self) -> int:
        """Observations the actor sees: the window (a family with a recurrent critic may differ)."""
        return int(self.cfg.window)

    def _make_actor(self) -> nn.Module:
        """The deterministic actor mu(s) over the actor's window."""
        cfg = self.cfg
        return Actor(self.obs_dim, self.actor_window, cfg.hidden, cfg.throttle_bias_init,
                     cfg.brake_bias_init, self.action_dim)  # fmt: skip

    def _make_critic(self) -> nn.Module:
        raise NotImplementedError

    def target(
        self,
        rewards: torch.Tensor,
        discounts: torch.Tensor,
        next_observations: torch.Tensor,
        next_action_windows: torch.Tensor,
    ) -> torch.Tensor:
        """y for the batch: r^(n) + d times the family's bootstrap value (d = 0: y = r)."""
        raise NotImplementedError

    def _policy_action(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The actor's action at ``obs`` for the actor loss, and its log-probability (or None)."""
        return self.actor(obs), None

    def critic_loss(self, td: torch.Tensor, y: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        """L(Q) from the TD errors ``td = y - Q(s, a)``: their weighted mean square (twins: the
        mean of L(Q_1), L(Q_2)); a family with another loss of its critic's outputs (a
        classification critic, which reads ``y``) overrides it."""
        return (weights * td.square()).mean()

    def critic_objective(self, critic_loss: torch.Tensor) -> torch.Tensor:
        """What the critic parameters descend, from the (mean) weighted critic loss."""
        raise NotImplementedError

    def actor_loss(self, q_pi: torch.Tensor, log_pi: torch.Tensor | None) -> torch.Tensor:
        """The actor's loss from Q(s, pi(s)) (and pi's log-probability, for a stochastic actor)."""
        raise NotImplementedError

    def bc_values(self, q: torch.Tensor, q_pi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Q(s, a) and Q(s, pi(s)) as the cloning term reads them (one row per sample)."""
        return q, q_pi

    def _after_actor_step(self) -> None:
        """Optimiser steps of the family's own parameters, after the actor's."""

    # --- acting ---------------------------------------------------------------------------------
    def act(self, obs_window: np.ndarray) -> np.ndarray:
        """Greedy action for one window ``(w, obs_dim)`` (exploration is added outside, or by
        :meth:`explore`)."""
        return self._greedy_action(self.actor, self._greedy, obs_window)

    def act_eval(self, obs_window: np.ndarray) -> np.ndarray:
        """The greedy action of a test or a race: :meth:`act` of the averaged actor when
        ``cfg.eval_ema_updates`` keeps one, of the online actor otherwise (the paper's)."""
        return self._greedy_action(self._eval_actor, self._greedy_eval, obs_window)

    def eval_preactivation(self, obs_window: np.ndarray) -> np.ndarray:
        """The output layer's pre-activations (before tanh / sigmoid) of the actor
        :meth:`act_eval` drives, for one window: how far into its squashing each output sits
        (``benchmarks/actor_saturation.py``; the DDPG family's ``preact_penalty`` bounds them)."""
        if not isinstance(self._eval_actor, Actor):
            raise TypeError(f"{type(self._eval_actor).__name__} has no pre-activation to read")
        with torch.no_grad():
            return self._eval_actor.preactivation(self._window_tensor(obs_window))[0].cpu().numpy()

    def eval_q(self, obs_window: np.ndarray, action: np.ndarray) -> float:
        """The critic's Q at one window and action, read as the update reads it (the window
        through the running observation statistics where ``cfg.obs_norm`` keeps them): what a
        trained critic has learnt along a test drive (``benchmarks/critic_values.py``)."""
        if not isinstance(self.critic, MLPCritic):
            raise TypeError(f"reads one MLP critic (the DDPG family's), not a "
                            f"{type(self.critic).__name__}")  # fmt: skip
        a = torch.as_tensor(action, dtype=torch.float32, device=self.device).reshape(1, -1)
        with torch.no_grad():
            return float(self.critic(self._window_tensor(obs_window), a)[0])

    def _greedy_action(
        self, actor: nn.Module, greedy: GreedyAct | None, obs_window: np.ndarray
    ) -> np.ndarray:
        """``actor``'s greedy action: through its hand-written forward where it has one."""
        if greedy is not None:
            if self.obs_norm is not None:
                obs_window = self.obs_norm.apply_np(obs_window)
            return greedy(obs_window)
        with torch.no_grad():
            return actor(self._window_tensor(obs_window))[0].cpu().numpy()

    def act_batch(self, obs_windows: np.ndarray) -> np.ndarray:
        """Greedy actions of the online actor for a batch of windows ``(cars, w, obs_dim)`` in
        one forward pass (the training loop's cars)."""
        with torch.no_grad():
            x = self.normalise(torch.from_numpy(obs_windows).to(self.device))
            return self.actor(x).cpu().numpy()

    def explore(self, obs_window: np.ndarray) -> np.ndarray:
        """The training loop's action for one window: the greedy action, to which the loop adds
        its noise (``uses_action_noise``); a stochastic policy samples instead."""
        return self.act(obs_window)

    def _window_tensor(self, obs_window: np.ndarray) -> torch.Tensor:
        """One window ``(w, obs_dim)`` as a batch of one ``(1, w, obs_dim)`` on the device."""
        x = torch.as_tensor(obs_window, dtype=torch.float32, device=self.device)
        return self.normalise(x.reshape(1, -1, self.obs_dim))

    def normalise(self, observations: torch.Tensor) -> torch.Tensor:
        """Observations (last axis ``obs_dim``) as the networks read them: through the running
        statistics with ``cfg.obs_norm``, unchanged otherwise."""
        return observations if self.obs_norm is None else self.obs_norm.apply(observations)

    def count_observations(self, observations: np.ndarray) -> None:
        """Add ``observations`` ``(k, obs_dim)`` to the running statistics (``cfg.obs_norm``;
        nothing otherwise). The entrant counts each stored transition's observation once."""
        if self.obs_norm is not None:
            self.obs_norm.update(observations)

    # --- learning -------------------------------------------------------------------------------
    _MLP_FIELDS = ("observations", "actions", "rewards", "next_observations", "discounts",
                   "weights")  # fmt: skip
    _LSTM_FIELDS = (*_MLP_FIELDS, "action_windows", "next_action_windows")

    def _tensors(
        self, batch: ReplayBatch, names: tuple[str, ...] = _LSTM_FIELDS
    ) -> dict[str, torch.Tensor]:
        tensors = {n: torch.from_numpy(getattr(batch, n)) for n in names}
        if self.device.type != "cpu":  # on the CPU: zero-copy views of the batch's arrays
            tensors = {n: t.to(self.device, non_blocking=True) for n, t in tensors.items()}
        if self.obs_norm is not None:  # with the statistics of this update
            for n in ("observations", "next_observations"):
                tensors[n] = self.obs_norm.apply(tensors[n])
        return tensors

    def update(
        self, batch: ReplayBatch, per_buffer: Any | None = None, bc: BCLoss | None = None
    ) -> UpdateInfo:
        """One gradient step on critic and actor, then the soft target update.

        ``per_buffer`` (a PrioritizedReplayBuffer) receives the batch's priorities; ``bc`` adds
        behaviour cloning of the batch's demonstration rows (its last ``bc.rows``, as
        ``buffers.DemoMix`` lays a batch out) to the actor's loss. The MLP actor and critic take
        the hand-written update (``mlp_update.py``): the mathematics of ``_update_autograd`` with
        no autograd graph, ~60 operators into preallocated buffers instead of ~160
        (``benchmarks/learner_throughput.py`` times both side by side).
        """
        if self.cfg.lr_decay_updates:
            self._decay_learning_rates()
        if self._mlp_update is None:
            return self._update_autograd(batch, per_buffer, bc)
        cfg, mlp = self.cfg, self._mlp_update
        t = self._tensors(batch, self._MLP_FIELDS)
        result = mlp.gradients(**t, action_grad=cfg.prioritized, bc=bc)
        self.critic_opt.step()
        self.actor_opt.step()
        self._soft_updates()
        if cfg.prioritized and per_buffer is not None:
            self.last_priorities = per_buffer.update_priorities(
                batch.indices, result.td.cpu().numpy(), result.grad_a.cpu().numpy()
            )
        self.updates += 1
        sum_q, sum_q_pi, sum_gq_td, sum_abs_td, bc_loss, preact_loss = result.stats
        n = len(batch.actions)
        return UpdateInfo(  # sum_gq_td = sum_i (-2/N w_i td_i) td_i = -2 L(Q)
            critic_loss=-0.5 * sum_gq_td, actor_loss=-sum_q_pi / n + bc_loss + preact_loss,
            q_mean=sum_q / n, td_abs_mean=sum_abs_td / n,
        )  # fmt: skip

    def lr_factor(self) -> float:
        """The learning rates' share of ``actor_lr`` and ``critic_lr`` at this update: 1 falling
        linearly to ``lr_final_fraction`` over ``lr_decay_updates`` (0: always 1). A function of
        the update count alone, so a resumed run takes up the schedule where it stopped."""
        cfg = self.cfg
        if not cfg.lr_decay_updates:
            return 1.0
        done = min(1.0, self.updates / cfg.lr_decay_updates)
        return 1.0 - (1.0 - cfg.lr_final_fraction) * done

    def _decay_learning_rates(self) -> None:
        factor = self.lr_factor()
        self.actor_opt.lr = self.cfg.actor_lr * factor
        self.critic_opt.lr = self.cfg.critic_lr * factor

    @staticmethod
    def _bc_loss(
        policy_action: torch.Tensor, actions: torch.Tensor, q: torch.Tensor, q_pi: torch.Tensor,
        bc: BCLoss,
    ) -> torch.Tensor:
        """The cloning term (``mlp_update.MLPUpdate._bc_gradient`` writes its gradient by hand):
        w mean|Q(s, mu(s))| / k sum_i m_i ||mu(s_i) - a_i||^2 over the last k rows."""
        demo = slice(len(actions) - bc.rows, None)
        per_row = (policy_action[demo] - actions[demo].detach()).square().sum(-1)
        if bc.q_filter:
            per_row = per_row * (q[demo].detach() > q_pi[demo].detach())
        return q_pi.detach().abs().mean() * (bc.weight / bc.rows) * per_row.sum()

    def _update_autograd(
        self, batch: ReplayBatch, per_buffer: Any | None = None, bc: BCLoss | None = None
    ) -> UpdateInfo:
        """``update`` through autograd: every family's, and the reference for the hand-written
        backend. With twin critics ``q`` and ``td`` are ``(2, B)``, row 0 for Q_1."""
        cfg = self.cfg
        b = self._tensors(batch)
        # a delayed family steps the actor and the targets on the d-th, 2d-th, ... update
        step_actor = (self.updates + 1) % self._policy_delay == 0

        # the critic loss, importance-weighted under PER, and the actor loss, both at the same
        # critic parameters
        actions = b["actions"].requires_grad_(cfg.prioritized)
        q, y, policy_action, log_pi, q_pi = self._critic_values(b, actions, step_actor)
        td = y - q
        critic_loss = self.critic_loss(td, y, b["weights"])
        q_1, td_1 = (q[0], td[0]) if self.twin_critics else (q, td)
        if cfg.prioritized:  # the priority needs grad_a Q(s_i, a_i) at the stored action
            (grad_a,) = torch.autograd.grad(q_1.sum(), actions, retain_graph=True)
        self._grad_flat.zero_()  # backward accumulates into the bound .grad views
        # each loss reaches only its own network's weights (no critic dW from the actor loss)
        # (the LSTM critic runs both sequences in one call, so its graph is shared and kept)
        self.critic_objective(critic_loss).backward(
            inputs=self._critic_params, retain_graph=self.critic.recurrent
        )
        if step_actor:
            actor_loss = self.actor_loss(q_pi, log_pi)
            if bc is not None:
                q_bc, q_pi_bc = self.bc_values(q, q_pi)
                actor_loss = actor_loss + self._bc_loss(
                    policy_action, b["actions"], q_bc, q_pi_bc, bc
                )
            actor_loss.backward(inputs=self._actor_params)
            self._last_actor_loss = float(actor_loss.detach())
        # every gradient is taken before any step: the actor's runs through the critic's weights
        self.critic_opt.step()
        if step_actor:
            self.actor_opt.step()
            self._after_actor_step()
            self._soft_updates()

        if cfg.prioritized and per_buffer is not None:
            self.last_priorities = per_buffer.update_priorities(
                batch.indices, td_1.detach().cpu().numpy(), grad_a.cpu().numpy()
            )
        self.updates += 1
        return UpdateInfo(
            critic_loss=float(critic_loss.detach()), actor_loss=self._last_actor_loss,
            q_mean=float(q.detach().mean()), td_abs_mean=float(td.detach().abs().mean()),
        )  # fmt: skip

    def _critic_values(
        self, b: dict[str, torch.Tensor], actions: torch.Tensor, step_actor: bool
    ) -> tuple[torch.Tensor, torch.Tensor, Any, Any, Any]:
        """``Q(s, a)``, the target ``y``, and on an actor step ``pi(s)``, its log-probability
        and ``Q(s, pi(s))`` (None between actor steps): eq. (1) from the family's ``target``,
        then the critic. Sharing the critic's state path between Q(s, a) and Q(s, pi(s)) skips
        ~20% of the update's FLOPs. A family whose target needs the critic's own pass on the
        next states (CrossQ) overrides this one step of the update."""
        obs = b["observations"]
        past_actions = b["action_windows"][:, :-1]  # empty unless the LSTM critic reads them
        y = self.target(b["rewards"], b["discounts"], b["next_observations"],
                        b["next_action_windows"])  # fmt: skip
        if not step_actor:  # between actor steps: the critics alone
            return self.critic(obs, actions, past_actions), y, None, None, None
        policy_action, log_pi = self._policy_action(obs)
        q, q_pi = self.critic.q_pair(obs, actions, policy_action, past_actions)
        return q, y, policy_action, log_pi, q_pi

    @torch.no_grad()
    def _soft_updates(self) -> None:
        """After an actor step: the soft target update over all weights at once,
        theta' += tau (theta - theta'), and the tests' average, theta_eval += (theta -
        theta_eval) / eval_ema_updates."""
        if self.moves_targets:
            self._target_flat.lerp_(self._target_source, self.cfg.tau)
        if self._eval_flat is not None:
            self._eval_flat.lerp_(self._actor_flat, self._eval_rate)

    @torch.no_grad()
    def sync_actor_copies(self) -> None:
        """Copy the online actor into the target actor and the tests' average: a warm start
        (behaviour cloning) moves the actor without updates, and copies that kept the random
        initialisation would drag it back for thousands of updates."""
        for copy_ in (self.actor_target, self.actor_eval):
            if copy_ is not None:
                copy_.load_state_dict(self.actor.state_dict())  # into the flat views

    # --- state ----------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Everything to resume or evaluate; only tensors and plain types (weights_only loads).

        Keys beyond :data:`CHECKPOINT_KEYS` are the family's (``checkpoint_keys``),
        ``actor_eval``, the tests' averaged actor, when ``cfg.eval_ema_updates``, and
        ``obs_norm``, the observation statistics, when ``cfg.obs_norm``.
        """
        state: dict[str, Any] = {
            "format": CHECKPOINT_FORMAT,
            "config": self.cfg.model_dump(mode="json"),
            "obs_dim": self.obs_dim,
            "action_dim": self.action_dim,
            "updates": self.updates,
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
        }
        if self.actor_target is not None:
            state["actor_target"] = self.actor_target.state_dict()
        if self.actor_eval is not None:
            state["actor_eval"] = self.actor_eval.state_dict()
        if self.obs_norm is not None:
            state["obs_norm"] = self.obs_norm.state_dict()
        state["critic_target"] = self.critic_target.state_dict()
        state["actor_opt"] = self.actor_opt.state_dict()
        state["critic_opt"] = self.critic_opt.state_dict()
        if self._generator is not None:
            state["generator"] = self._generator.get_state()
            state["last_actor_loss"] = self._last_actor_loss
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        if self.actor_target is not None:
            self.actor_target.load_state_dict(state["actor_target"])
        if self.actor_eval is not None:
            self.actor_eval.load_state_dict(state["actor_eval"])
        if self.obs_norm is not None:
            self.obs_norm.load_state_dict(state["obs_norm"])
        self.critic_target.load_state_dict(state["critic_target"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        if self._generator is not None:
            self._generator.set_state(state["generator"].cpu())  # CPU bytes on every device
            self._last_actor_loss = float(state.get("last_actor_loss", 0.0))
        self.updates = int(state.get("updates", 0))


CHECKPOINT_FORMAT = 1
"""The ``format`` key of every agent checkpoint written by :meth:`Agent.state_dict`."""
CHECKPOINT_KEYS = (
    "format", "config", "obs_dim", "action_dim", "actor", "critic", "critic_target", "actor_opt",
    "critic_opt",
)  # fmt: skip
"""Keys of every agent checkpoint; a family's ``checkpoint_keys`` adds its own."""
