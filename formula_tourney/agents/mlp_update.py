"""The DDPG update for the MLP actor and critic with hand-written backward passes.

Same mathematics as the autograd update of the DDPG family (``core.py``'s skeleton with
``ddpg.py``'s equations (1)-(5)), for every DDPG variant whose critic is :class:`MLPCritic`
(WIN, MS, PER). On one CPU thread the autograd engine and its ~160 small operators cost more
than a quarter on top of the update's GEMMs (``benchmarks/learner_throughput.py`` times both
updates side by side). Written by hand the update is ~60 operators, all writing into buffers
allocated once per batch size (``out=``), with no graph to build:

* forward: ``h = relu(x W^T + b)`` per layer (``addmm`` into a buffer, then ``relu_``); the
  actor's is :class:`~formula_tourney.agents.networks.ActorPass`, which acting runs too;
* ReLU backward: ``threshold_backward`` on the layer's output, in place on the gradient;
* bias gradients: a sum over the batch (measured faster than a ones column in the GEMM);
* the critic's two evaluations ``Q(s, a)`` and ``Q(s, mu(s))`` share ``W2h relu(W1 s) + b2``
  and are stacked as ``2B`` rows after it, so their last layer, its ReLU mask and the
  gradient at its input are one operator each; each loss still reaches only its own network's
  weights (the critic's weight gradients read the first ``B`` rows only);
* PER's ``grad_a Q(s_i, a_i)`` is ``(relu'(h2) * w_out) W2a``, one GEMM on a mask computed
  anyway;
* Adam runs once per network on flat views (parameters, gradients and moments are contiguous);
* with demonstrations, behaviour cloning in the actor's loss (``BCLoss``) adds its gradient at
  ``mu`` before the squash's backward: one (B, 3) block, nothing when it is off;
* the saturation term (``preact_penalty``) adds its gradient at the pre-activations ``z`` after
  the squash's backward: one clamp, one subtraction and one add, nothing when it is off;
* a classification critic (``critic_bins``): the last layer gives logits ``L`` over the bins,
  ``Q = softmax(L) c`` with ``c`` the bin centres, so ``dQ/dL = p (c - Q)`` row by row, and the
  critic's cross-entropy to the HL-Gauss targets ``t`` has ``dL(Q)/dL = w (p - t) / N``. Both
  pass back through the last layer by one GEMM each instead of the one-output critic's
  product with its weight row. With ``critic_mse_weight`` the squared error of ``Q`` joins the
  cross-entropy: ``w dL(Q)/dQ dQ/dL`` adds to the logits' gradient before that GEMM.

The parameters stay the ``nn.Module`` parameters (state_dict keys and checkpoints unchanged);
gradients are written into the parameters' ``.grad``, which the agent binds to views of one flat
buffer, the same buffer its autograd update accumulates into and its Adam steps read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch

from formula_tourney.agents.networks import (
    Actor,
    ActorPass,
    MLPCritic,
    addmm_operands,
    hl_gauss_targets,
)

aten = torch.ops.aten


class UpdateResult(NamedTuple):
    """What the agent reads back from one update (tensors are workspace views, reused later)."""

    # [sum Q(s, a), sum Q(s, mu(s)), sum dL/dQ * td (= -2 L(Q); with bins -2 times the
    #  cross-entropy), sum |td|, cloning term (or 0), saturation term (or 0)]
    stats: list[float]
    td: torch.Tensor  # (B,) y - Q(s, a)
    grad_a: torch.Tensor | None  # (B, A) grad_a Q(s_i, a_i), PER only


class BCLoss(NamedTuple):
    """Behaviour cloning in the actor's loss: its weight, the demonstration rows of every batch
    (its last ``rows`` rows, ``buffers.DemoMix``'s layout) and whether the Q-filter applies."""

    weight: float
    rows: int
    q_filter: bool = True


class Saturation(NamedTuple):
    """The actor loss's saturation term: ``weight`` times the squared excess of each
    pre-activation beyond +-its bound, the steer's or the pedals' (the DDPG settings
    ``preact_penalty``, ``preact_bound``)."""

    weight: float
    steer_bound: float
    pedal_bound: float


@dataclass
class _Dense:
    """One linear layer: its weight, ``(b, W^T)`` as the GEMMs read them, and its gradients."""

    w: torch.Tensor
    b: torch.Tensor | None
    wt: torch.Tensor
    gw: torch.Tensor | None
    gb: torch.Tensor | None

    @property
    def operands(self) -> tuple[torch.Tensor, torch.Tensor]:
        return self.b, self.wt  # type: ignore[return-value]


def _dense(layer: torch.nn.Linear, with_grads: bool = True) -> _Dense:
    """The layer's views; ``with_grads``: its ``.grad`` views too, which must be bound."""
    w, b = layer.weight, layer.bias
    gw = gb = None
    if with_grads:
        gw, gb = w.grad, None if b is None else b.grad
        if gw is None or (b is not None and gb is None):
            raise ValueError("MLPUpdate: the online parameters' .grad must be bound buffers")
    return _Dense(w.detach(), None if b is None else b.detach(), w.detach().t(), gw, gb)


class _Workspace:
    """Activations and gradients of one update at batch size ``B``, allocated once.

    The target pass runs first and reuses the online pass's buffers (its values are dead once
    ``y`` is formed), which keeps the working set small enough to stay in cache.
    """

    def __init__(self, batch: int, h1a: int, h2a: int, h1c: int, h2c: int, w_out: torch.Tensor,
                 action_dim: int = 3, bins: int = 1):  # fmt: skip
        B = batch  # noqa: N806
        z = {"dtype": torch.float32, "device": w_out.device}
        self.batch = B
        self.action_dim = action_dim
        # actor (also the target actor): its forward's buffers, and their gradients
        self.actor = ActorPass(B, (h1a, h2a), w_out, action_dim)
        self.a1, self.a2, self.pi = self.actor.a1, self.actor.a2, self.actor.pi
        self.ga1, self.ga2 = torch.empty(B, h1a, **z), torch.empty(B, h2a, **z)
        self.gpi, self.gz = torch.empty(B, action_dim, **z), torch.empty(B, action_dim, **z)
        self.gpi_steer, self.gpi_pedals = self.gpi[:, :1], self.gpi[:, 1:]
        self.gz_steer, self.gz_pedals = self.gz[:, :1], self.gz[:, 1:]
        # critic: shared state path, then [Q(s, a); Q(s, mu(s))] stacked as 2B rows
        self.c1, self.gc1 = torch.empty(B, h1c, **z), torch.empty(B, h1c, **z)
        self.base = torch.empty(B, h2c, **z)
        self.h2 = torch.empty(2 * B, h2c, **z)  # relu(base + [a; mu(s)] W2a^T)
        self.m2 = torch.empty(2 * B, h2c, **z)  # relu'(h2) * w_out = dQ/d(h2 pre-activation)
        if bins == 1:  # the critic's output weight per row (a view)
            self.w_out_rows = w_out.expand(2 * B, -1)
        else:  # a classification critic's logits, dQ/dlogits and the loss's gradient at them
            self.logits = torch.empty(2 * B, bins, **z)
            self.dq_dlogits = torch.empty(2 * B, bins, **z)
            self.g_logits = torch.empty(B, bins, **z)
            self.g_logits_t = self.g_logits.t()
            self.dh2 = torch.empty(2 * B, h2c, **z)  # dQ/dh2 before the ReLU's mask
        self.q = torch.empty(2 * B, 1, **z)
        self.g2 = torch.empty(B, h2c, **z)  # the critic loss's gradient at h2's pre-activation
        self.gq = torch.empty(B, 1, **z)  # dL(Q)/dQ(s, a)
        self.zeros = torch.zeros(B, 1, **z)  # addcmul's addend: gq in one operator
        self.y, self.td = torch.empty(B, 1, **z), torch.empty(B, 1, **z)
        self.grad_a = torch.empty(B, action_dim, **z)
        self.z_excess = torch.empty(B, action_dim, **z)  # z beyond the saturation term's bounds
        self.z_excess_steer, self.z_excess_pedals = self.z_excess[:, :1], self.z_excess[:, 1:]
        # [4], [5]: the cloning and saturation terms, written only when they are on
        self.stats = torch.zeros(6, **z)
        self.h2_q, self.h2_pi = self.h2[:B], self.h2[B:]
        self.m2_q, self.m2_pi = self.m2[:B], self.m2[B:]
        self.q_q, self.q_rows = self.q[:B], self.q.view(2, B)
        self.gq_flat, self.td_flat = self.gq.view(-1), self.td.view(-1)
        self.stats_q, self.stats_td, self.stats_abs = self.stats[0:2], self.stats[2], self.stats[3]
        self.stats_bc, self.stats_preact = self.stats[4], self.stats[5]
        self.q_pi_flat = self.q[B:].view(-1)
        self._bc: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
        # transposed views read by the weight-gradient GEMMs (dW = g^T x)
        self.gq_t, self.g2_t, self.gc1_t = self.gq.t(), self.g2.t(), self.gc1.t()
        self.gz_t, self.ga2_t, self.ga1_t = self.gz.t(), self.ga2.t(), self.ga1.t()

    def bc_buffers(self, rows: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The cloning term's buffers for the last ``rows`` rows: (a - mu) (rows, 3), the
        Q-filter's mask (rows, 1) and the term's scale, allocated once."""
        if self._bc is None or self._bc[0].shape[0] != rows:
            z = {"dtype": self.q.dtype, "device": self.q.device}
            self._bc = (torch.empty(rows, self.action_dim, **z), torch.empty(rows, 1, **z),
                        torch.empty((), **z))  # fmt: skip
        return self._bc


class MLPUpdate:
    """Forward and backward of one DDPG step without autograd: gradients into the parameters'
    bound ``.grad`` views (the agent then runs Adam and the soft target update).

    Parameters and targets are the agent's; this object holds only views of them and the
    per-batch-size workspace. Parameters must not be rebound after construction: the agent keeps
    them as views of its flat tensor, loading a checkpoint copies in place, and
    ``copy.deepcopy`` of an agent rebuilds it rather than copying its tensors one by one.
    """

    def __init__(
        self, actor: Actor, critic: MLPCritic, actor_target: Actor, critic_target: MLPCritic,
        saturation: Saturation | None = None, mse_weight: float = 0.0,
    ) -> None:
        if actor.window != critic.window:
            raise ValueError("MLPUpdate: actor and critic must read the same window")
        self.window = critic.window
        self.a_l1, self.a_l2, self.a_out = (_dense(m) for m in (actor.l1, actor.l2, actor.out))
        self.c_l1, self.c_l2, self.c_act, self.c_out = (
            _dense(m) for m in (critic.l1, critic.l2, critic.l2_action, critic.out)
        )
        self.actor_layers = tuple(d.operands for d in (self.a_l1, self.a_l2, self.a_out))
        self.target_actor_layers = tuple(
            addmm_operands(m) for m in (actor_target.l1, actor_target.l2, actor_target.out)
        )
        self.tc_l1, self.tc_l2, self.tc_act, self.tc_out = (
            _dense(m, with_grads=False)
            for m in (critic_target.l1, critic_target.l2, critic_target.l2_action,
                      critic_target.out)
        )  # fmt: skip
        self.sizes = (
            actor.l1.out_features, actor.l2.out_features,
            critic.l1.out_features, critic.l2.out_features,
        )  # fmt: skip
        self.action_dim = actor.out.out_features
        self.bins = critic.bins
        if self.bins > 1:
            self.edges, self.centres = critic.edges, critic.centres.view(-1, 1)
            self._critic = critic  # its sigma_bins may follow a schedule (DDPG's warm-up)
        self.saturation = saturation if saturation is not None and saturation.weight else None
        self.mse_weight = float(mse_weight)  # read on the bins' path alone
        self._ws: _Workspace | None = None

    def _workspace(self, batch: int) -> _Workspace:
        if self._ws is None or self._ws.batch != batch:
            self._ws = _Workspace(batch, *self.sizes, self.c_out.w, self.action_dim, self.bins)
        return self._ws

    # --- forward passes ------------------------------------------------------------------------
    def _target(
        self, ws: _Workspace, x_next: torch.Tensor, rewards: torch.Tensor, discounts: torch.Tensor
    ) -> None:
        """Eq. (1) into ``ws.y``: r + d Q'(s', mu'(s')) with the target networks."""
        mu = ws.actor(x_next, self.target_actor_layers)
        torch.relu_(torch.addmm(self.tc_l1.b, x_next, self.tc_l1.wt, out=ws.c1))
        h2 = torch.addmm(self.tc_l2.b, ws.c1, self.tc_l2.wt, out=ws.base)  # base: a free buffer
        torch.relu_(h2.addmm_(mu, self.tc_act.wt))
        if self.bins == 1:
            q_next = torch.addmm(self.tc_out.b, h2, self.tc_out.wt, out=ws.y)
        else:  # the softmax's mean of the bin centres
            logits = torch.addmm(self.tc_out.b, h2, self.tc_out.wt, out=ws.logits[: ws.batch])
            q_next = torch.mm(torch.softmax(logits, 1), self.centres, out=ws.y)
        torch.addcmul(rewards, discounts, q_next, out=ws.y)

    def _critic_forward(self, ws: _Workspace, x: torch.Tensor, actions: torch.Tensor) -> None:
        """``ws.q`` = [Q(s, a); Q(s, mu(s))], sharing ``base = W2h relu(W1 s) + b2``."""
        torch.relu_(torch.addmm(self.c_l1.b, x, self.c_l1.wt, out=ws.c1))
        torch.addmm(self.c_l2.b, ws.c1, self.c_l2.wt, out=ws.base)
        torch.addmm(ws.base, actions, self.c_act.wt, out=ws.h2_q)
        torch.addmm(ws.base, ws.pi, self.c_act.wt, out=ws.h2_pi)
        torch.relu_(ws.h2)
        if self.bins == 1:
            torch.addmm(self.c_out.b, ws.h2, self.c_out.wt, out=ws.q)
            return
        torch.addmm(self.c_out.b, ws.h2, self.c_out.wt, out=ws.logits)
        ws.p = torch.softmax(ws.logits, 1)
        torch.mm(ws.p, self.centres, out=ws.q)

    # --- backward passes -----------------------------------------------------------------------
    @staticmethod
    def _dense_backward(g: torch.Tensor, g_t: torch.Tensor, x: torch.Tensor, layer: _Dense) -> None:
        """Weight and bias gradients of ``x W^T + b`` given ``g = dL/d(output)`` (``g_t = g^T``)."""
        torch.mm(g_t, x, out=layer.gw)
        if layer.gb is not None:
            torch.sum(g, 0, out=layer.gb)

    def _critic_backward(self, ws: _Workspace, x: torch.Tensor, actions: torch.Tensor) -> None:
        """Critic weight gradients of eq. (2), from the first ``B`` rows only.

        Also leaves ``ws.m2`` = dQ/d(h2 pre-activation) for both row blocks: the actor's
        gradient and PER's grad_a Q read it.
        """
        if self.bins == 1:
            aten.threshold_backward.grad_input(ws.w_out_rows, ws.h2, 0, grad_input=ws.m2)
            torch.mul(ws.m2_q, ws.gq, out=ws.g2)
            self._dense_backward(ws.gq, ws.gq_t, ws.h2_q, self.c_out)
        else:
            # dQ/dlogits = p (c - Q) row by row, then through the last layer and the ReLU
            torch.sub(self.centres.view(1, -1), ws.q, out=ws.dq_dlogits).mul_(ws.p)
            if self.mse_weight:  # the squared error of Q itself: dL/dlogits = gq dQ/dlogits
                ws.g_logits.addcmul_(ws.dq_dlogits[: ws.batch], ws.gq, value=self.mse_weight)
            torch.mm(ws.dq_dlogits, self.c_out.w, out=ws.dh2)
            aten.threshold_backward.grad_input(ws.dh2, ws.h2, 0, grad_input=ws.m2)
            # the cross-entropy's gradient, g_logits, through the last layer and the ReLU
            torch.mm(ws.g_logits, self.c_out.w, out=ws.g2)
            aten.threshold_backward.grad_input(ws.g2, ws.h2_q, 0, grad_input=ws.g2)
            self._dense_backward(ws.g_logits, ws.g_logits_t, ws.h2_q, self.c_out)
        self._dense_backward(ws.g2, ws.g2_t, actions, self.c_act)
        self._dense_backward(ws.g2, ws.g2_t, ws.c1, self.c_l2)
        torch.mm(ws.g2, self.c_l2.w, out=ws.gc1)
        aten.threshold_backward.grad_input(ws.gc1, ws.c1, 0, grad_input=ws.gc1)
        self._dense_backward(ws.gc1, ws.gc1_t, x, self.c_l1)

    @staticmethod
    def _bc_gradient(ws: _Workspace, actions: torch.Tensor, bc: BCLoss) -> None:
        """Adds the cloning term's dL/dmu to ``ws.gpi`` and its value to ``ws.stats_bc``.

        L_bc = w mean|Q(s, mu(s))| / k sum_i m_i ||mu(s_i) - a_i||^2 over the batch's last ``k``
        rows (the demonstrations), m_i = [Q(s_i, a_i) > Q(s_i, mu(s_i))] under the Q-filter;
        the scale is a constant (no gradient through it), as in TD3+BC. All on tensors: no
        host round trip inside the update.
        """
        B, k = ws.batch, bc.rows  # noqa: N806
        diff, keep, coef = ws.bc_buffers(k)
        torch.sub(ws.pi[B - k:], actions[B - k:], out=diff)
        if bc.q_filter:
            diff.mul_(torch.gt(ws.q_q[B - k:], ws.q[2 * B - k:], out=keep))
        torch.linalg.vector_norm(ws.q_pi_flat, 1, out=coef).mul_(bc.weight / (B * k))
        ws.gpi[B - k:].addcmul_(diff, coef, value=2.0)
        torch.dot(diff.view(-1), diff.view(-1), out=ws.stats_bc).mul_(coef)

    @staticmethod
    def _saturation_gradient(ws: _Workspace, sat: Saturation) -> None:
        """Adds the saturation term's dL/dz to ``ws.gz`` and its value to ``ws.stats_preact``:
        L = w / B sum_i sum_j e_ij^2 with e = z - clamp(z, -bound_j, bound_j), so dL/dz =
        2 w e / B (``DDPGAgent.actor_loss`` is the same term through autograd)."""
        excess = ws.z_excess
        torch.clamp(ws.actor.z_steer, -sat.steer_bound, sat.steer_bound, out=ws.z_excess_steer)
        torch.clamp(ws.actor.z_pedals, -sat.pedal_bound, sat.pedal_bound,
                    out=ws.z_excess_pedals)  # fmt: skip
        torch.sub(ws.actor.z, excess, out=excess)
        ws.gz.add_(excess, alpha=2.0 * sat.weight / ws.batch)
        flat = excess.view(-1)
        torch.dot(flat, flat, out=ws.stats_preact).mul_(sat.weight / ws.batch)

    def _actor_backward(
        self, ws: _Workspace, x: torch.Tensor, actions: torch.Tensor, bc: BCLoss | None
    ) -> None:
        """Actor gradients of eq. (3): -mean Q(s, mu(s)) through the action only, plus the
        cloning term ``bc`` of the demonstrated ``actions`` when it is given."""
        # dL/dmu = -1/N dQ/da at a = mu(s); the scale is applied to the (B, 3) product
        torch.mm(ws.m2_pi, self.c_act.w, out=ws.gpi).mul_(-1.0 / ws.batch)
        if bc is not None:
            self._bc_gradient(ws, actions, bc)
        aten.tanh_backward.grad_input(ws.gpi_steer, ws.actor.pi_steer, grad_input=ws.gz_steer)
        pedals_backward = (aten.sigmoid_backward if ws.actor.sigmoid_pedals
                           else aten.tanh_backward)  # the pedal action mode: tanh  # fmt: skip
        pedals_backward.grad_input(ws.gpi_pedals, ws.actor.pi_pedals, grad_input=ws.gz_pedals)
        if self.saturation is not None:
            self._saturation_gradient(ws, self.saturation)
        self._dense_backward(ws.gz, ws.gz_t, ws.a2, self.a_out)
        torch.mm(ws.gz, self.a_out.w, out=ws.ga2)
        aten.threshold_backward.grad_input(ws.ga2, ws.a2, 0, grad_input=ws.ga2)
        self._dense_backward(ws.ga2, ws.ga2_t, ws.a1, self.a_l2)
        torch.mm(ws.ga2, self.a_l2.w, out=ws.ga1)
        aten.threshold_backward.grad_input(ws.ga1, ws.a1, 0, grad_input=ws.ga1)
        self._dense_backward(ws.ga1, ws.ga1_t, x, self.a_l1)

    def _cross_entropy(self, ws: _Workspace, weights: torch.Tensor) -> None:
        """A classification critic's loss at ``(s, a)``: ``ws.g_logits`` = w (p - t) / N, its
        gradient at the logits, and -2 times its value into ``ws.stats_td`` (where the squared
        error's -2 L(Q) goes), t the HL-Gauss histogram of ``ws.y``."""
        B = ws.batch  # noqa: N806
        target = hl_gauss_targets(ws.y.view(-1), self.edges, self._critic.sigma_bins)
        torch.sub(ws.p[:B], target, out=ws.g_logits).mul_(weights / B)
        log_p = torch.log_softmax(ws.logits[:B], 1)
        per_row = target.mul_(log_p).sum(1)  # sum_k t_k log p_k
        torch.dot(per_row, weights.view(-1), out=ws.stats_td).mul_(2.0 / B)

    # --- the step ------------------------------------------------------------------------------
    @torch.no_grad()
    def gradients(
        self,
        observations: torch.Tensor,
        actions: torch.Tensor,
        rewards: torch.Tensor,
        next_observations: torch.Tensor,
        discounts: torch.Tensor,
        weights: torch.Tensor,
        action_grad: bool = False,
        bc: BCLoss | None = None,
    ) -> UpdateResult:
        """Both networks' gradients into their ``.grad`` (the optimizer step is the caller's).

        Observations are windows ``(B, w, D)``; rewards, discounts and weights ``(B,)``; ``bc``
        clones the batch's last ``bc.rows`` rows (the demonstrations) in the actor's loss.
        """
        B = actions.shape[0]  # noqa: N806
        ws = self._workspace(B)
        if observations.shape[1] != self.window:
            raise ValueError(f"MLPUpdate: windows of {self.window} expected")
        x, x_next = observations.view(B, -1), next_observations.view(B, -1)
        self._target(ws, x_next, rewards.view(B, 1), discounts.view(B, 1))
        ws.actor(x, self.actor_layers)
        self._critic_forward(ws, x, actions)
        # dL/dQ(s_i, a_i) of eq. (2): -2/N w_i (y_i - Q_i)
        torch.sub(ws.y, ws.q_q, out=ws.td)
        torch.addcmul(ws.zeros, ws.td, weights.view(B, 1), value=-2.0 / B, out=ws.gq)
        if self.bins > 1:
            self._cross_entropy(ws, weights.view(B, 1))
            if self.mse_weight:  # its value beside the cross-entropy's: -2 w L(Q)
                ws.stats_td.add_(torch.dot(ws.gq_flat, ws.td_flat), alpha=self.mse_weight)
        self._critic_backward(ws, x, actions)
        self._actor_backward(ws, x, actions, bc)
        grad_a = torch.mm(ws.m2_q, self.c_act.w, out=ws.grad_a) if action_grad else None
        torch.sum(ws.q_rows, 1, out=ws.stats_q)
        if self.bins == 1:
            torch.dot(ws.gq_flat, ws.td_flat, out=ws.stats_td)
        torch.linalg.vector_norm(ws.td_flat, 1, out=ws.stats_abs)
        return UpdateResult(ws.stats.tolist(), ws.td_flat, grad_a)
