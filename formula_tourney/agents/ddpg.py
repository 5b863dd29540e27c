"""The one update rule for every variant (DDPG, and TD3 and SAC as its settings), as equations.

Paper, "Algorithms" (numbering ours):

    (1) y_i   = sum_{k<m} gamma^k r_{i+k} + d_i Q'(s_{i+m}, mu'(s_{i+m}))      m = 1 unless MS
        d_i   = gamma^m, or 0 on a premature end (the adopted target bootstraps on max-steps)
    (2) L(Q)  = 1/N sum_i w_i (y_i - Q(s_i, a_i))^2                          w_i = 1 unless PER
    (3) grad J ~ 1/N sum_i grad_a Q(s_i, a)|_{a = mu(s_i)} grad_theta mu(s_i)   (same Q as (2))
    (4) theta' <- tau theta + (1 - tau) theta'
    (5) p_i   = delta_i^2 + lambda3 |grad_a Q(s_i, a_i)|^2 + eps                    PER only

Variants differ only by configuration: the window ``w`` (WIN) is in the observation tensors' shape,
the LSTM critic is a different critic module fed the window's past actions, n-step (MS) arrives as
the batch's summed rewards and discounts, PER as weights plus a priority update.

Beyond the paper, ``cfg.algorithm`` turns the same update into TD3 or SAC (Stable-Baselines3's
lesson: DDPG is TD3 with one critic and no delay). Both use twin critics Q_1, Q_2; replay,
windows, n-step, PER weights and priorities (from Q_1) and the adopted target stay as above:

    TD3 (1')  y_i = r^(n) + d_i min_j Q'_j(s', clip(mu'(s') + clip(e, -c, c), box)), e ~ N(0, s^2)
        (2')  L = sum_j 1/N sum_i w_i (y_i - Q_j(s_i, a_i))^2
        (3')  the actor ascends Q_1(s, mu(s)); (3') and (4) only every policy_delay-th update
    SAC (1'') y_i = r^(n) + d_i (min_j Q'_j(s', a') - alpha log pi(a'|s')),  a' ~ pi(.|s')
        (3'') J = 1/N sum_i alpha log pi(a~_i|s_i) - min_j Q_j(s_i, a~_i), a~_i ~ pi(.|s_i)
              reparameterised; (4) moves the critics' targets only (SAC has no target actor)
        (6)   L(alpha) = -1/N sum_i log alpha (log pi(a~_i|s_i) + H_target)

Both losses are taken at the same critic parameters for every algorithm (as OpenAI Baselines'
DDPG; TD3's and SAC's reference code take the actor loss after the critic step), and SAC's alpha
is the value before this update's step in (1''), (3'') and (6), as in SB3.
"""

from __future__ import annotations

import contextlib
import copy
import io
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn

from formula_tourney.agents.mlp_update import BCLoss, MLPUpdate
from formula_tourney.agents.networks import (
    Actor,
    GreedyAct,
    LSTMCritic,
    MLPCritic,
    SquashedGaussianActor,
    TwinCritic,
)
from formula_tourney.agents.noise import ACTION_HIGH, ACTION_LOW
from formula_tourney.agents.replay import ReplayBatch
from formula_tourney.agents.variants import AgentConfig
from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write_bytes


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


class DDPGAgent:
    """Actor, critic, their targets and optimizers; ``update`` is the whole learning rule.

    ``cfg.algorithm`` picks DDPG (the paper's), TD3 or SAC; the class stays the one agent.
    """

    def __init__(
        self,
        cfg: AgentConfig,
        obs_dim: int,
        action_dim: int = 3,
        device: str = "cpu",
        seed: int | None = None,
    ) -> None:
        if seed is not None:  # initial weights depend on the seed alone
            torch.manual_seed(seed)
        self.cfg = cfg
        self.obs_dim = int(obs_dim)
        self.action_dim = int(action_dim)
        self.device = resolve_device(device)
        # LSTM variants keep a plain actor on the current observation (paper: LSTM actor unstable)
        self.actor_window = 1 if cfg.lstm_critic else cfg.window
        actor_cls = SquashedGaussianActor if cfg.algorithm == "sac" else Actor
        self.actor: nn.Module = actor_cls(
            obs_dim, self.actor_window, cfg.hidden, cfg.throttle_bias_init, cfg.brake_bias_init
        ).to(self.device)
        self.critic: nn.Module
        if cfg.twin_critics:  # TD3, SAC (variants.py refuses the LSTM critic for them)
            self.critic = TwinCritic(obs_dim, action_dim, cfg.window, cfg.hidden)
        elif cfg.lstm_critic:
            self.critic = LSTMCritic(
                obs_dim,
                action_dim,
                cfg.window,
                cfg.lstm_state_units,
                cfg.lstm_hidden,
                cfg.hidden[1],
            )
        else:
            self.critic = MLPCritic(obs_dim, action_dim, cfg.window, cfg.hidden)
        self.critic.to(self.device)
        # SAC bootstraps from its current policy: no target actor
        self.actor_target: nn.Module | None = None
        if cfg.algorithm != "sac":
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
        # what the soft update (4) moves the targets towards: all online weights, or (SAC, no
        # target actor) the critic's alone
        self._target_source = self._online_flat
        if self.actor_target is None:
            self._target_source = self._online_flat[n_actor:]
        # TD3 steps the actor and the targets every policy_delay-th update; DDPG and SAC every one
        self._policy_delay = cfg.policy_delay if cfg.algorithm == "td3" else 1
        self._last_actor_loss = 0.0  # reported on TD3's critic-only updates
        # TD3's smoothing noise and SAC's samples come from the agent's own generator, so the
        # seed alone fixes them and checkpoints and copies carry the stream
        self._generator: torch.Generator | None = None
        if cfg.algorithm != "ddpg":
            self._generator = torch.Generator(device=self.device)
            self._generator.manual_seed(
                seed if seed is not None else int(torch.randint(2**62, ()).item())
            )
        self._action_low = torch.as_tensor(ACTION_LOW, device=self.device)
        self._action_high = torch.as_tensor(ACTION_HIGH, device=self.device)
        # SAC's temperature: log alpha, its own gradient buffer and Adam
        self.log_alpha: torch.Tensor | None = None
        self.alpha_opt: FusedAdam | None = None
        self.target_entropy = cfg.entropy_target(self.action_dim)
        if cfg.algorithm == "sac":
            self.log_alpha = torch.full(
                (1,), float(np.log(cfg.alpha_init)), device=self.device, requires_grad=True
            )
            self.log_alpha.grad = torch.zeros_like(self.log_alpha)
            self.alpha_opt = FusedAdam(
                [self.log_alpha], self.log_alpha, self.log_alpha.grad, lr=cfg.alpha_lr
            )
        # the MLP critic's update is written out by hand (mlp_update.py); the LSTM's, and TD3's
        # and SAC's twin critics, use autograd
        self._mlp_update: MLPUpdate | None = None
        if isinstance(self.critic, MLPCritic) and isinstance(self.actor, Actor):
            assert self.actor_target is not None
            self._mlp_update = MLPUpdate(
                self.actor, self.critic, self.actor_target, self.critic_target
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

    def __deepcopy__(self, memo: dict[int, Any]) -> DDPGAgent:
        """A rebuilt agent with copied state: a field-by-field copy would give the networks
        separate tensors instead of views of the flat weights, and the soft update and Adam's
        flat step would then silently miss them."""
        with torch.random.fork_rng(devices=[]):  # the fresh init must not move the global RNG
            clone = DDPGAgent(self.cfg, self.obs_dim, self.action_dim, device=str(self.device))
        clone.load_state_dict(self.state_dict())
        clone.last_priorities = copy.deepcopy(self.last_priorities, memo)
        clone._last_actor_loss = self._last_actor_loss
        return clone

    # --- acting ---------------------------------------------------------------------------------
    def act(self, obs_window: np.ndarray) -> np.ndarray:
        """Greedy action for one window ``(w, obs_dim)``: mu(s), or SAC's squashed mean
        ``c + k tanh(m(s))`` (exploration is added outside, or by :meth:`explore`)."""
        return self._greedy_action(self.actor, self._greedy, obs_window)

    def act_eval(self, obs_window: np.ndarray) -> np.ndarray:
        """The greedy action of a test or a race: :meth:`act` of the averaged actor when
        ``cfg.eval_ema_updates`` keeps one, of the online actor otherwise (the paper's)."""
        return self._greedy_action(self._eval_actor, self._greedy_eval, obs_window)

    def _greedy_action(
        self, actor: nn.Module, greedy: GreedyAct | None, obs_window: np.ndarray
    ) -> np.ndarray:
        """``actor``'s greedy action: through its hand-written forward where it has one."""
        if greedy is not None:
            return greedy(obs_window)
        with torch.no_grad():
            return actor(self._window_tensor(obs_window))[0].cpu().numpy()

    def explore(self, obs_window: np.ndarray) -> np.ndarray:
        """The training loop's action for one window: SAC's sample ``a ~ pi(.|s)``; for DDPG and
        TD3 the greedy action, to which the loop adds its noise (``cfg.uses_action_noise``)."""
        if not isinstance(self.actor, SquashedGaussianActor):
            return self.act(obs_window)
        with torch.no_grad():
            action, _ = self.actor.sample(self._window_tensor(obs_window), self._generator)
        return action[0].cpu().numpy()

    def _window_tensor(self, obs_window: np.ndarray) -> torch.Tensor:
        """One window ``(w, obs_dim)`` as a batch of one ``(1, w, obs_dim)`` on the device."""
        x = torch.as_tensor(obs_window, dtype=torch.float32, device=self.device)
        return x.reshape(1, -1, self.obs_dim)

    @property
    def alpha(self) -> torch.Tensor | None:
        """SAC's temperature ``exp(log alpha)`` (detached); None for DDPG and TD3."""
        return None if self.log_alpha is None else self.log_alpha.detach().exp()

    # --- learning -------------------------------------------------------------------------------
    _MLP_FIELDS = ("observations", "actions", "rewards", "next_observations", "discounts",
                   "weights")  # fmt: skip
    _LSTM_FIELDS = (*_MLP_FIELDS, "action_windows", "next_action_windows")

    def _tensors(
        self, batch: ReplayBatch, names: tuple[str, ...] = _LSTM_FIELDS
    ) -> dict[str, torch.Tensor]:
        tensors = {n: torch.from_numpy(getattr(batch, n)) for n in names}
        if self.device.type == "cpu":  # zero-copy views of the batch's arrays
            return tensors
        return {n: t.to(self.device, non_blocking=True) for n, t in tensors.items()}

    @torch.no_grad()
    def target(
        self,
        rewards: torch.Tensor,
        discounts: torch.Tensor,
        next_observations: torch.Tensor,
        next_action_windows: torch.Tensor,
    ) -> torch.Tensor:
        """Eq. (1): y = r^(n) + d Q'(s', mu'(s')), with d = 0 where the target is y = r; TD3's
        (1') and SAC's (1'') draw their noise from the agent's generator."""
        if isinstance(self.actor, SquashedGaussianActor):  # (1'') a' ~ pi(.|s'), entropy bonus
            assert self.log_alpha is not None
            next_action, log_pi = self.actor.sample(next_observations, self._generator)
            q_next = self.critic_target(next_observations, next_action).amin(0)
            return rewards + discounts * (q_next - self.log_alpha.exp() * log_pi)
        assert self.actor_target is not None
        next_action = self.actor_target(next_observations)
        if self.cfg.algorithm == "td3":  # (1') target policy smoothing, kept inside the box
            cfg = self.cfg
            noise = torch.randn(next_action.shape, generator=self._generator,
                                device=next_action.device) * cfg.policy_noise  # fmt: skip
            noise = noise.clamp(-cfg.noise_clip, cfg.noise_clip)
            next_action = torch.clamp(next_action + noise, self._action_low, self._action_high)
        q_next = self.critic_target(next_observations, next_action, next_action_windows)
        if self.cfg.twin_critics:  # clipped double-Q
            q_next = q_next.amin(0)
        return rewards + discounts * q_next

    def update(
        self, batch: ReplayBatch, per_buffer: Any | None = None, bc: BCLoss | None = None
    ) -> UpdateInfo:
        """One gradient step on critic and actor, then the soft target update.

        ``per_buffer`` (a PrioritizedReplayBuffer) receives eq. (5)'s priorities for the batch;
        ``bc`` adds behaviour cloning of the batch's demonstration rows (its last ``bc.rows``,
        as ``replay.DemoMix`` lays a batch out) to the actor's loss.
        MLP critics take the hand-written update (``mlp_update.py``): the mathematics of
        ``_update_autograd`` with no autograd graph, ~60 operators into preallocated buffers
        instead of ~160 (``learner_throughput.py`` times both side by side).
        """
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
        sum_q, sum_q_pi, sum_gq_td, sum_abs_td, bc_loss = result.stats
        n = len(batch.actions)
        return UpdateInfo(  # sum_gq_td = sum_i (-2/N w_i td_i) td_i = -2 L(Q)
            critic_loss=-0.5 * sum_gq_td, actor_loss=-sum_q_pi / n + bc_loss,
            q_mean=sum_q / n, td_abs_mean=sum_abs_td / n,
        )  # fmt: skip

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
        """``update`` through autograd: the LSTM critic's, TD3's and SAC's, and the reference
        for the MLP's. With twin critics ``q`` and ``td`` are ``(2, B)``, row 0 for Q_1."""
        cfg = self.cfg
        b = self._tensors(batch)
        obs = b["observations"]
        past_actions = b["action_windows"][:, :-1]  # empty unless the LSTM critic reads them
        sac = isinstance(self.actor, SquashedGaussianActor)
        # TD3 steps the actor and the targets on the d-th, 2d-th, ... update (Fujimoto's order)
        step_actor = (self.updates + 1) % self._policy_delay == 0

        # (1) target: r^(n) + d * Q'(s', mu'(s')); d = 0 is y = r (premature end); (1'), (1'')
        y = self.target(b["rewards"], b["discounts"], b["next_observations"],
                        b["next_action_windows"])  # fmt: skip

        # (2) critic loss, importance-weighted under PER, and (3) actor loss -Q(s, mu(s)), both
        # at the same critic parameters (as OpenAI Baselines' DDPG); sharing the critic's state
        # path between Q(s, a) and Q(s, mu(s)) skips ~20% of the update's FLOPs
        actions = b["actions"].requires_grad_(cfg.prioritized)
        if step_actor:
            if sac:  # a~ ~ pi(.|s), reparameterised: (3'') reaches the actor through a~
                policy_action, log_pi = self.actor.sample(obs, self._generator)
            else:
                policy_action = self.actor(obs)
            q, q_pi = self.critic.q_pair(obs, actions, policy_action, past_actions)
        else:  # TD3 between actor steps: the critics alone
            q = self.critic(obs, actions, past_actions)
        td = y - q
        critic_loss = (b["weights"] * td.square()).mean()  # twins: the mean of L(Q_1), L(Q_2)
        q_1, td_1 = (q[0], td[0]) if cfg.twin_critics else (q, td)
        if cfg.prioritized:  # (5) needs grad_a Q(s_i, a_i) at the stored action
            (grad_a,) = torch.autograd.grad(q_1.sum(), actions, retain_graph=True)
        self._grad_flat.zero_()  # backward accumulates into the bound .grad views
        # each loss reaches only its own network's weights (no critic dW from the actor loss)
        # (the LSTM critic runs both sequences in one call, so its graph is shared and kept)
        # (2') twins: each critic descends its own loss, so the sum of both
        critic_objective = 2.0 * critic_loss if cfg.twin_critics else critic_loss
        critic_objective.backward(inputs=self._critic_params, retain_graph=self.critic.recurrent)
        if step_actor:
            if sac:  # (3'') and (6), with alpha as it was before this update
                assert self.log_alpha is not None and self.log_alpha.grad is not None
                alpha = self.log_alpha.detach().exp()
                actor_loss = (alpha * log_pi - q_pi.amin(0)).mean()
                alpha_loss = -(self.log_alpha * (log_pi.detach() + self.target_entropy)).mean()
                self.log_alpha.grad.zero_()
                alpha_loss.backward(inputs=[self.log_alpha])
            elif cfg.twin_critics:  # (3') TD3's actor follows Q_1
                actor_loss = -q_pi[0].mean()
            else:
                actor_loss = -q_pi.mean()
            if bc is not None:  # TD3's Q_1 / SAC's min of twins, as its actor loss reads
                q_bc, q_pi_bc = q, q_pi
                if cfg.twin_critics:
                    q_bc, q_pi_bc = (q.amin(0), q_pi.amin(0)) if sac else (q[0], q_pi[0])
                actor_loss = actor_loss + self._bc_loss(
                    policy_action, b["actions"], q_bc, q_pi_bc, bc
                )
            actor_loss.backward(inputs=self._actor_params)
            self._last_actor_loss = float(actor_loss.detach())
        # every gradient is taken before any step: the actor's runs through the critic's weights
        self.critic_opt.step()
        if step_actor:
            self.actor_opt.step()
            if self.alpha_opt is not None:
                self.alpha_opt.step()
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

    @torch.no_grad()
    def _soft_updates(self) -> None:
        """After an actor step: (4) the soft target update over all weights at once,
        theta' += tau (theta - theta'), and the tests' average, theta_eval += (theta -
        theta_eval) / eval_ema_updates."""
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

    # --- persistence ----------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Everything to resume or evaluate; only tensors and plain types (weights_only loads).

        Keys beyond :data:`CHECKPOINT_KEYS` are the algorithm's (:data:`ALGORITHM_CHECKPOINT_KEYS`):
        the target actor (DDPG, TD3), the noise generator's state (TD3, SAC), log alpha and its
        Adam (SAC); and ``actor_eval``, the tests' averaged actor, when ``cfg.eval_ema_updates``.
        """
        state: dict[str, Any] = {
            "format": 1,
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
        state["critic_target"] = self.critic_target.state_dict()
        state["actor_opt"] = self.actor_opt.state_dict()
        state["critic_opt"] = self.critic_opt.state_dict()
        if self._generator is not None:
            state["generator"] = self._generator.get_state()
            state["last_actor_loss"] = self._last_actor_loss
        if self.log_alpha is not None and self.alpha_opt is not None:
            state["log_alpha"] = self.log_alpha.detach().clone()
            state["alpha_opt"] = self.alpha_opt.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        if self.actor_target is not None:
            self.actor_target.load_state_dict(state["actor_target"])
        if self.actor_eval is not None:
            self.actor_eval.load_state_dict(state["actor_eval"])
        self.critic_target.load_state_dict(state["critic_target"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        if self._generator is not None:
            self._generator.set_state(state["generator"].cpu())  # CPU bytes on every device
            self._last_actor_loss = float(state.get("last_actor_loss", 0.0))
        if self.log_alpha is not None and self.alpha_opt is not None:
            with torch.no_grad():
                self.log_alpha.copy_(state["log_alpha"].reshape(self.log_alpha.shape))
            self.alpha_opt.load_state_dict(state["alpha_opt"])
        self.updates = int(state.get("updates", 0))


def save_checkpoint(
    agent: DDPGAgent, path: str | Path, extra: dict[str, Any] | None = None
) -> Path:
    """Write ``agent`` (and plain ``extra`` metadata) atomically to ``path``."""
    state = agent.state_dict()
    if extra:
        state["extra"] = extra
    buf = io.BytesIO()
    torch.save(state, buf)
    return atomic_write_bytes(path, buf.getvalue())


CHECKPOINT_KEYS = (
    "format", "config", "obs_dim", "action_dim", "actor", "critic", "critic_target", "actor_opt",
    "critic_opt",
)  # fmt: skip
"""Keys of every agent checkpoint; :data:`ALGORITHM_CHECKPOINT_KEYS` adds each algorithm's."""
ALGORITHM_CHECKPOINT_KEYS: dict[str, tuple[str, ...]] = {
    "ddpg": ("actor_target",),
    "td3": ("actor_target", "generator"),
    "sac": ("generator", "log_alpha", "alpha_opt"),
}


def load_checkpoint(path: str | Path, device: str = "cpu") -> tuple[DDPGAgent, dict[str, Any]]:
    """Rebuild the agent from a checkpoint with ``weights_only=True`` (no pickled code runs).

    Every way a file can be wrong (not a checkpoint, a missing key, a config this version does
    not accept, weights of another variant's shapes) is one UserInputError naming the file.
    """
    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"checkpoint {path} does not exist")
    dev = resolve_device(device)
    try:
        state = torch.load(path, map_location=dev, weights_only=True)
    except Exception as err:  # corrupt or foreign file; torch's own text runs over many lines
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise UserInputError(f"checkpoint {path} cannot be read: {first}") from None
    if not isinstance(state, dict) or state.get("format") != 1:
        raise UserInputError(f"checkpoint {path} is not a formula-tourney agent checkpoint")
    missing = [k for k in CHECKPOINT_KEYS if k not in state]
    if missing:
        raise UserInputError(f"checkpoint {path} is incomplete: no {', '.join(missing)}")
    try:
        cfg = AgentConfig.model_validate(state["config"])
        obs_dim, action_dim = int(state["obs_dim"]), int(state["action_dim"])
    except (ValueError, TypeError) as err:  # pydantic's ValidationError is a ValueError
        first = str(err).splitlines()[0]
        raise UserInputError(f"checkpoint {path} has a bad agent config: {first}") from None
    if obs_dim < 1 or action_dim < 1:
        raise UserInputError(f"checkpoint {path} has bad sizes {obs_dim} x {action_dim}")
    wanted = ALGORITHM_CHECKPOINT_KEYS[cfg.algorithm]
    if cfg.eval_ema_updates:
        wanted += ("actor_eval",)
    missing = [k for k in wanted if k not in state]
    if missing:
        raise UserInputError(
            f"checkpoint {path} is incomplete for {cfg.algorithm}: no {', '.join(missing)}"
        )
    agent = DDPGAgent(cfg, obs_dim, action_dim, device=str(dev))
    try:
        agent.load_state_dict(state)
    except (RuntimeError, KeyError, ValueError, TypeError) as err:
        first = str(err).strip().splitlines()[0]
        raise UserInputError(
            f"checkpoint {path}: its weights do not fit its config {cfg.name} ({first})"
        ) from None
    return agent, dict(state.get("extra", {}))
