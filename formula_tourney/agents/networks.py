"""Actors and critics: deterministic actor, squashed Gaussian actor, MLP, twin and LSTM critics.

Inputs are observation windows ``(B, w, obs_dim)`` (``w = 1`` for plain DDPG). The actor maps the
flattened window to (steer, throttle, brake) with tanh on steer (-1..1) and sigmoid on the pedals
(0..1), matching the env's ``Box([-1, 0, 0], [1, 1, 1])``. The MLP critic follows Lillicrap et al.:
the action joins after the first hidden layer. The LSTM critic (paper, "LSTM critic network")
places its LSTM after the concatenation of the state stream and the action, over the window of
the last w (state, action) pairs; only the critic is recurrent, as the paper found an LSTM actor
unstable. Beyond the paper, TD3 and SAC use :class:`TwinCritic` (two MLP critics for clipped
double-Q), SAC and CrossQ the :class:`SquashedGaussianActor` (tanh-squashed Gaussian, mapped
affinely onto the same box), and CrossQ the :class:`BNTwinCritic` (batch-normalised critics).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

FINAL_INIT = 3e-3  # Lillicrap et al.: small final layers so initial outputs and Q are near zero
# the action box as centre + scale * tanh(u): steer in [-1, 1], throttle and brake in [0, 1]
ACTION_CENTRE = (0.0, 0.5, 0.5)
ACTION_SCALE = (1.0, 0.5, 0.5)
PEDAL_BOX = ((0.0, 0.0), (1.0, 1.0))  # centre and scale of the pedal action mode's box
LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # SAC's clamp of log sigma (Haarnoja et al.'s code, SB3)


def _fan_in_init(layer: nn.Linear) -> nn.Linear:
    """DDPG paper init: uniform(+-1/sqrt(fan_in)) for hidden layers."""
    bound = 1.0 / layer.weight.shape[1] ** 0.5
    nn.init.uniform_(layer.weight, -bound, bound)
    nn.init.uniform_(layer.bias, -bound, bound)
    return layer


def _final_init(layer: nn.Linear) -> nn.Linear:
    nn.init.uniform_(layer.weight, -FINAL_INIT, FINAL_INIT)
    nn.init.uniform_(layer.bias, -FINAL_INIT, FINAL_INIT)
    return layer


def pedal_squash(action_dim: int):  # type: ignore[no-untyped-def]
    """The pedal columns' squash onto the env's box: sigmoid onto [0, 1] for (steer, throttle,
    brake), tanh onto [-1, 1] for the pedal action mode's (steer, pedal)."""
    return torch.sigmoid if action_dim == 3 else torch.tanh


class Actor(nn.Module):
    """mu(s): flattened window -> hidden -> (tanh steer, sigmoid throttle, sigmoid brake), or
    (tanh steer, tanh pedal) in the pedal action mode (``action_dim = 2``)."""

    def __init__(
        self,
        obs_dim: int,
        window: int = 1,
        hidden: tuple[int, int] = (400, 300),
        throttle_bias: float = 0.0,
        brake_bias: float = 0.0,
        action_dim: int = 3,
    ) -> None:
        super().__init__()
        self.window = window
        self.l1 = _fan_in_init(nn.Linear(obs_dim * window, hidden[0]))
        self.l2 = _fan_in_init(nn.Linear(hidden[0], hidden[1]))
        self.out = _final_init(nn.Linear(hidden[1], action_dim))
        self.squash_pedals = pedal_squash(action_dim)
        with torch.no_grad():
            # pedals start near chosen pressures: at 0.5 throttle and 0.5 brake the car never
            # moves; the one pedal starts at tanh(throttle_bias) of throttle
            self.out.bias[1] += throttle_bias
            if action_dim == 3:
                self.out.bias[2] += brake_bias

    def preactivation(self, obs_window: torch.Tensor) -> torch.Tensor:
        """z: the output layer's values before the squash (what the saturation term reads)."""
        x = obs_window[:, -self.window :].flatten(1)
        x = torch.relu_(self.l1(x))
        x = torch.relu_(self.l2(x))
        return self.out(x)

    def squash(self, z: torch.Tensor) -> torch.Tensor:
        """The action of pre-activations ``z``: tanh steer, the pedals' squash."""
        return torch.cat([torch.tanh(z[:, :1]), self.squash_pedals(z[:, 1:])], dim=1)

    def forward(self, obs_window: torch.Tensor) -> torch.Tensor:
        return self.squash(self.preactivation(obs_window))


def addmm_operands(layer: nn.Linear) -> tuple[torch.Tensor, torch.Tensor]:
    """``(b, W^T)`` of a layer as detached views, what ``addmm(b, x, W^T)`` reads; views follow
    in-place weight updates and checkpoint loads."""
    return layer.bias.detach(), layer.weight.detach().t()


class ActorPass:
    """``Actor.forward`` written into buffers allocated once for batch size ``B``.

    The one hand-written actor forward: acting (``B = 1``, right after updates that evict the
    caches) and the autograd-free update (online and target actor) both run it. No module calls,
    no ``cat``, no fresh tensors: at batch 1 those cost more than the arithmetic.
    """

    def __init__(
        self, batch: int, hidden: tuple[int, int], like: torch.Tensor, action_dim: int = 3
    ) -> None:
        self.batch = batch
        self.a1, self.a2 = like.new_empty(batch, hidden[0]), like.new_empty(batch, hidden[1])
        self.z, self.pi = like.new_empty(batch, action_dim), like.new_empty(batch, action_dim)
        self.sigmoid_pedals = action_dim == 3
        self.squash_pedals = pedal_squash(action_dim)
        # steer and pedal columns as views made once (a slice costs ~1.4 us per call)
        self.z_steer, self.z_pedals = self.z[:, :1], self.z[:, 1:]
        self.pi_steer, self.pi_pedals = self.pi[:, :1], self.pi[:, 1:]

    def __call__(
        self, x: torch.Tensor, layers: tuple[tuple[torch.Tensor, torch.Tensor], ...]
    ) -> torch.Tensor:
        """mu(x) into ``self.pi`` from the ``(b, W^T)`` of the actor's three layers."""
        (b1, w1), (b2, w2), (b3, w3) = layers
        torch.relu_(torch.addmm(b1, x, w1, out=self.a1))
        torch.relu_(torch.addmm(b2, self.a1, w2, out=self.a2))
        torch.addmm(b3, self.a2, w3, out=self.z)
        torch.tanh(self.z_steer, out=self.pi_steer)
        self.squash_pedals(self.z_pedals, out=self.pi_pedals)
        return self.pi


class GreedyAct:
    """mu(s) for one observation window: the acting step, through :class:`ActorPass`."""

    def __init__(self, actor: Actor) -> None:
        self.window = actor.window
        self.layers = tuple(addmm_operands(m) for m in (actor.l1, actor.l2, actor.out))
        hidden = (actor.l1.out_features, actor.l2.out_features)
        self.forward = ActorPass(1, hidden, actor.l1.weight, actor.out.out_features)

    @torch.no_grad()
    def __call__(self, obs_window: np.ndarray) -> np.ndarray:
        """Action ``(action_dim,)`` for one window ``(w, obs_dim)`` (the actor reads its last
        rows)."""
        x = torch.as_tensor(obs_window, dtype=torch.float32, device=self.forward.pi.device)
        pi = self.forward(x[-self.window :].reshape(1, -1), self.layers)
        return pi[0].cpu().numpy().copy()


HL_GAUSS_SIGMA_BINS = 0.75
"""The histogram loss's spread in bin widths: Farebrother et al.'s (2024) recommended ratio."""


class MLPCritic(nn.Module):
    """Q(s, a): flattened state window -> h1, [h1, a] -> h2 -> Q (action at the second layer).

    With ``layer_norm`` (beyond the paper: RLPD, Ball et al. 2023) each hidden layer's
    pre-activation passes a LayerNorm before its ReLU, which bounds the critic's features and so
    its extrapolation to actions the buffer never holds; off, the norms are identities and the
    critic is Lillicrap's, parameter for parameter.

    With ``bins > 1`` (beyond the paper: a classification critic, Farebrother et al. 2024) the
    last layer gives logits over ``bins`` equal bins spanning ``value_range``, and Q is the
    softmax's mean of the bin centres: ``forward`` and ``q_pair`` return that value, and
    ``logits_pair`` the logits the cross-entropy loss (``hl_gauss_targets``, with a normal of
    ``sigma_bins`` bin widths) trains.
    """

    recurrent = False

    def __init__(
        self,
        obs_dim: int,
        action_dim: int = 3,
        window: int = 1,
        hidden: tuple[int, int] = (400, 300),
        layer_norm: bool = False,
        bins: int = 1,
        value_range: tuple[float, float] = (0.0, 0.0),
        sigma_bins: float = HL_GAUSS_SIGMA_BINS,
    ) -> None:
        super().__init__()
        self.layer_norm = layer_norm
        self.bins = int(bins)
        self.sigma_bins = float(sigma_bins)  # the HL-Gauss target's spread (hl_gauss_targets)
        self.window = window
        self.l1 = _fan_in_init(nn.Linear(obs_dim * window, hidden[0]))
        # the second layer's weight is split into its h1 and action columns: W2 [h1, a] =
        # W2h h1 + W2a a, which avoids copying a (B, 403) concatenation in every pass
        l2 = _fan_in_init(nn.Linear(hidden[0] + action_dim, hidden[1]))
        self.l2 = nn.Linear(hidden[0], hidden[1])
        self.l2_action = nn.Linear(action_dim, hidden[1], bias=False)
        with torch.no_grad():
            self.l2.weight.copy_(l2.weight[:, : hidden[0]])
            self.l2.bias.copy_(l2.bias)
            self.l2_action.weight.copy_(l2.weight[:, hidden[0] :])
        self.out = _final_init(nn.Linear(hidden[1], self.bins))
        self.norm1: nn.Module = nn.LayerNorm(hidden[0]) if layer_norm else nn.Identity()
        self.norm2: nn.Module = nn.LayerNorm(hidden[1]) if layer_norm else nn.Identity()
        if self.bins > 1:
            low, high = value_range
            edges = torch.linspace(float(low), float(high), self.bins + 1)
            self.register_buffer("edges", edges)
            self.register_buffer("centres", 0.5 * (edges[1:] + edges[:-1]))

    def value(self, out: torch.Tensor) -> torch.Tensor:
        """Q ``(B,)`` from the last layer's output ``(B, bins)``: itself with one output, the
        softmax's mean of the bin centres with bins."""
        if self.bins == 1:
            return out.squeeze(1)
        return torch.softmax(out, dim=1) @ self.centres

    def forward(
        self,
        obs_window: torch.Tensor,
        action: torch.Tensor,
        past_actions: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Q values ``(B,)``; ``past_actions`` is ignored (only the LSTM critic reads it)."""
        h = torch.relu_(self.norm1(self.l1(obs_window[:, -self.window :].flatten(1))))
        h = torch.relu_(self.norm2(torch.addmm(self.l2(h), action, self.l2_action.weight.t())))
        return self.value(self.out(h))

    def q_pair(
        self,
        obs_window: torch.Tensor,
        action: torch.Tensor,
        policy_action: torch.Tensor,
        past_actions: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(Q(s, a), Q(s, mu(s)))`` sharing the state path ``W2h relu(W1 s)``.

        Only the action columns and the last layer are evaluated twice: the actor's pass through
        the critic costs ~1% instead of ~20% of an update's FLOPs. The second value is detached
        from the state path, so the actor loss reaches the actor through the action alone.
        """
        out, q_pi = self.logits_pair(obs_window, action, policy_action)
        return self.value(out), q_pi

    def logits_pair(
        self, obs_window: torch.Tensor, action: torch.Tensor, policy_action: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`q_pair` with the last layer's output at ``(s, a)`` ``(B, bins)`` in place of
        its value: the logits a classification critic's loss reads."""
        h = torch.relu_(self.norm1(self.l1(obs_window[:, -self.window :].flatten(1))))
        base = self.l2(h)
        w_a = self.l2_action.weight.t()
        out = self.out(torch.relu_(self.norm2(torch.addmm(base, action, w_a))))
        q_pi = self.value(self.out(
            torch.relu_(self.norm2(torch.addmm(base.detach(), policy_action, w_a)))
        ))  # fmt: skip
        return out, q_pi


def hl_gauss_targets(
    y: torch.Tensor, edges: torch.Tensor, sigma_bins: float = HL_GAUSS_SIGMA_BINS
) -> torch.Tensor:
    """The histogram loss's target (Imani & White 2018; "HL-Gauss", Farebrother et al. 2024):
    a normal of mean ``y`` (clipped into the bins' span) and spread ``sigma_bins`` bin widths,
    its mass per bin ``(B, bins)``, renormalised to the span. A regression target becomes a
    class distribution whose neighbouring bins share the mass, so the mean of the bin centres
    under it is ``y`` to within the bins' resolution."""
    low, high = float(edges[0]), float(edges[-1])
    sigma = sigma_bins * (high - low) / (len(edges) - 1)
    y = y.clamp(low, high)
    cdf = torch.special.erf((edges[None, :] - y[:, None]) / (sigma * 2.0**0.5))
    mass = cdf[:, 1:] - cdf[:, :-1]
    return mass / (cdf[:, -1:] - cdf[:, :1])


class TwinCritic(nn.Module):
    """Q1 and Q2 for clipped double-Q (TD3, SAC): two independently initialised MLP critics.

    Values are stacked ``(2, B)`` (row 0 is Q1), so the target's ``min`` is one reduction and
    each critic's loss one term of a sum.
    """

    recurrent = False

    def __init__(
        self,
        obs_dim: int,
        action_dim: int = 3,
        window: int = 1,
        hidden: tuple[int, int] = (400, 300),
        layer_norm: bool = False,
    ) -> None:
        super().__init__()
        self.window = window
        self.layer_norm = layer_norm
        self.q1 = MLPCritic(obs_dim, action_dim, window, hidden, layer_norm)
        self.q2 = MLPCritic(obs_dim, action_dim, window, hidden, layer_norm)

    def forward(
        self,
        obs_window: torch.Tensor,
        action: torch.Tensor,
        past_actions: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``(2, B)``: [Q1(s, a); Q2(s, a)]."""
        return torch.stack([self.q1(obs_window, action), self.q2(obs_window, action)])

    def q_pair(
        self,
        obs_window: torch.Tensor,
        action: torch.Tensor,
        policy_action: torch.Tensor,
        past_actions: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(Q(s, a), Q(s, pi(s)))``, each ``(2, B)``, each critic sharing its state path."""
        q1, q1_pi = self.q1.q_pair(obs_window, action, policy_action)
        q2, q2_pi = self.q2.q_pair(obs_window, action, policy_action)
        return torch.stack([q1, q2]), torch.stack([q1_pi, q2_pi])


class BNCritic(nn.Module):
    """CrossQ's Q(s, a) (Bhatt et al. 2024): [flattened window, a] -> BN -> (Linear -> BN ->
    ReLU) x 2 -> Q.

    Batch normalisation on the input and after each hidden layer; in training mode it
    normalises by the batch's statistics, so the CrossQ update feeds (s, a) and (s', a') as one
    joint batch and both halves see the same normalisation. In eval mode (the actor loss,
    acting) it uses the running statistics (``momentum`` per training pass).
    """

    recurrent = False

    def __init__(
        self,
        obs_dim: int,
        action_dim: int = 3,
        window: int = 1,
        hidden: tuple[int, int] = (256, 256),
        momentum: float = 0.01,
    ) -> None:
        super().__init__()
        self.window = window
        self.bn_in = nn.BatchNorm1d(obs_dim * window + action_dim, momentum=momentum)
        self.l1 = _fan_in_init(nn.Linear(obs_dim * window + action_dim, hidden[0]))
        self.bn1 = nn.BatchNorm1d(hidden[0], momentum=momentum)
        self.l2 = _fan_in_init(nn.Linear(hidden[0], hidden[1]))
        self.bn2 = nn.BatchNorm1d(hidden[1], momentum=momentum)
        self.out = _final_init(nn.Linear(hidden[1], 1))

    def forward(self, obs_window: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q values ``(B,)``."""
        x = self.bn_in(torch.cat([obs_window[:, -self.window :].flatten(1), action], dim=1))
        x = torch.relu(self.bn1(self.l1(x)))
        x = torch.relu(self.bn2(self.l2(x)))
        return self.out(x).squeeze(1)


class BNTwinCritic(TwinCritic):
    """CrossQ's Q1 and Q2: :class:`TwinCritic`'s pair and stacking with two :class:`BNCritic`
    s (CrossQ reads values only, never ``q_pair``)."""

    def __init__(
        self,
        obs_dim: int,
        action_dim: int = 3,
        window: int = 1,
        hidden: tuple[int, int] = (256, 256),
        momentum: float = 0.01,
    ) -> None:
        nn.Module.__init__(self)  # TwinCritic's own critics are MLPs: these are built here
        self.window = window
        self.layer_norm = False
        self.q1 = BNCritic(obs_dim, action_dim, window, hidden, momentum)
        self.q2 = BNCritic(obs_dim, action_dim, window, hidden, momentum)


class SquashedGaussianActor(nn.Module):
    """SAC's pi(a|s): u ~ N(m(s), sigma(s)^2), a = c + k tanh(u) onto the action box.

    ``c = (0, 0.5, 0.5)`` and ``k = (1, 0.5, 0.5)`` map tanh's (-1, 1) onto steer (-1..1) and the
    pedals (0..1); in the pedal action mode ``c = (0, 0)``, ``k = (1, 1)``. The density of ``a``
    is that of ``u`` divided by the map's Jacobian
    ``k (1 - tanh(u)^2)`` per dimension (Haarnoja et al. 2018, appendix C, with the affine factor
    ``k``). ``forward`` is the greedy action ``c + k tanh(m)``; since ``(1 + tanh(z/2)) / 2 =
    sigmoid(z)``, halving the pedal bias inits starts the mean pedals where the deterministic
    actor's start.
    """

    def __init__(
        self,
        obs_dim: int,
        window: int = 1,
        hidden: tuple[int, int] = (256, 256),
        throttle_bias: float = 0.0,
        brake_bias: float = 0.0,
        action_dim: int = 3,
    ) -> None:
        super().__init__()
        self.window = window
        self.l1 = _fan_in_init(nn.Linear(obs_dim * window, hidden[0]))
        self.l2 = _fan_in_init(nn.Linear(hidden[0], hidden[1]))
        self.mean = _final_init(nn.Linear(hidden[1], action_dim))
        self.log_std = _final_init(nn.Linear(hidden[1], action_dim))
        centre, scale = (ACTION_CENTRE, ACTION_SCALE) if action_dim == 3 else PEDAL_BOX
        with torch.no_grad():
            if action_dim == 3:
                self.mean.bias[1] += throttle_bias / 2
                self.mean.bias[2] += brake_bias / 2
            else:  # the pedal starts at tanh(throttle_bias), as the deterministic actor's
                self.mean.bias[1] += throttle_bias
        self.register_buffer("centre", torch.tensor(centre), persistent=False)
        self.register_buffer("scale", torch.tensor(scale), persistent=False)

    def distribution(self, obs_window: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(m, log sigma)`` of the pre-squash Gaussian, log sigma clamped to [-20, 2]."""
        x = obs_window[:, -self.window :].flatten(1)
        x = torch.relu(self.l2(torch.relu(self.l1(x))))
        return self.mean(x), self.log_std(x).clamp(LOG_STD_MIN, LOG_STD_MAX)

    def squash(self, u: torch.Tensor) -> torch.Tensor:
        """``c + k tanh(u)``: a pre-squash sample onto the action box."""
        return torch.addcmul(self.centre, self.scale, torch.tanh(u))

    def log_prob(self, u: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
        """``log pi(a|s)`` ``(B,)`` of ``a = squash(u)``: the Gaussian's log density of ``u``
        minus ``sum log(k (1 - tanh(u)^2))``.

        ``log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u))`` stays finite where tanh(u)
        rounds to +-1 (the identity used by SpinningUp and SB3).
        """
        z = (u - mean) * torch.exp(-log_std)
        gauss = -0.5 * z.square() - log_std - 0.5 * math.log(2 * math.pi)
        log_det = 2.0 * (math.log(2.0) - u - nn.functional.softplus(-2.0 * u))
        return (gauss - log_det - torch.log(self.scale.to(u.dtype))).sum(-1)

    def sample(
        self, obs_window: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised sample ``a ~ pi(.|s)`` ``(B, 3)`` and its ``log pi(a|s)`` ``(B,)``."""
        mean, log_std = self.distribution(obs_window)
        eps = torch.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
        u = mean + log_std.exp() * eps
        return self.squash(u), self.log_prob(u, mean, log_std)

    def forward(self, obs_window: torch.Tensor) -> torch.Tensor:
        """The greedy action ``c + k tanh(m(s))`` ``(B, 3)``."""
        return self.squash(self.distribution(obs_window)[0])


class LSTMCritic(nn.Module):
    """Q over a window: per step [relu(W s_k), a_k] -> LSTM -> last output -> MLP head -> Q.

    Sizes were chosen for CPU cost: the LSTM input is the state stream's width, so a 128-unit
    stream and 64 LSTM units keep a full update at roughly a third of the MLP variant's rate
    (128-unit LSTMs over 8 steps measured ~17 updates/s at batch 256 on one thread).
    """

    recurrent = True

    def __init__(
        self,
        obs_dim: int,
        action_dim: int = 3,
        window: int = 4,
        state_units: int = 128,
        lstm_units: int = 64,
        head_units: int = 300,
    ) -> None:
        super().__init__()
        self.window = window
        self.state = _fan_in_init(nn.Linear(obs_dim, state_units))
        self.lstm = nn.LSTM(state_units + action_dim, lstm_units, batch_first=True)
        self.head = _fan_in_init(nn.Linear(lstm_units, head_units))
        self.out = _final_init(nn.Linear(head_units, 1))

    def forward(
        self,
        obs_window: torch.Tensor,
        action: torch.Tensor,
        past_actions: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Q values ``(B,)`` of taking ``action`` after the window's ``w-1`` ``past_actions``."""
        stream = torch.relu(self.state(obs_window[:, -self.window :]))
        return self._q_from_stream(stream, self._action_seq(action, past_actions, stream))

    def _action_seq(
        self, action: torch.Tensor, past_actions: torch.Tensor | None, stream: torch.Tensor
    ) -> torch.Tensor:
        """The window's actions: ``w-1`` past ones from the buffer, then ``action``."""
        if past_actions is None or past_actions.shape[1] == 0:
            return action[:, None, :].expand(-1, stream.shape[1], -1)
        return torch.cat([past_actions[:, -(self.window - 1) :], action[:, None, :]], 1)

    def _q_from_stream(self, stream: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        seq, _ = self.lstm(torch.cat([stream, actions], dim=2))
        return self.out(torch.relu(self.head(seq[:, -1]))).squeeze(1)

    def q_pair(
        self,
        obs_window: torch.Tensor,
        action: torch.Tensor,
        policy_action: torch.Tensor,
        past_actions: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(Q(s, a), Q(s, mu(s)))``: one state stream, both sequences in one 2B-row LSTM call
        (bigger GEMMs run faster than two half-size ones)."""
        stream = torch.relu(self.state(obs_window[:, -self.window :]))
        both = torch.cat([stream, stream.detach()], dim=0)
        actions = torch.cat([self._action_seq(action, past_actions, stream),
                             self._action_seq(policy_action, past_actions, stream)], 0)  # fmt: skip
        q, q_pi = self._q_from_stream(both, actions).chunk(2)
        return q, q_pi
