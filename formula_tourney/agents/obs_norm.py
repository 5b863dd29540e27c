"""Running observation normalisation: each telemetry value standardised by the statistics of
every observation the learner has stored so far (beyond the paper).

The sensors already scale each value by a fixed physical range (``sim/sensors.py``), chosen so
typical values lie within about +-1 on the built-in tracks. Per value, the spread a learner
actually sees is far from that: the lookahead curvatures sit near 0 on a flowing track, a
wheel's slip near its own small band. Standardising every input to zero mean and unit variance
by running statistics (Andrychowicz et al. 2021, "What matters in on-policy RL"; the running
statistics norm of SimBa, Lee et al. 2024; SB3's ``VecNormalize``) gives every input the same
weight at the first layer from the first update on.

One :class:`RunningObsNorm` belongs to one agent: the actor's and the critics' inputs pass it at
acting, at testing and in every update (observations and next observations of the batch, with
the statistics of the moment, as SB3 normalises replayed observations at sampling time). The
statistics are part of the agent's state, so a checkpoint drives with the statistics it was
trained with. Every counted observation enters exactly once (Chan et al.'s parallel update in
float64: Gymnasium's ``RunningMeanStd``, which its ``NormalizeObservation`` wrapper keeps), so a
run gives the same statistics whatever the number of cars or the update order.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium.wrappers.utils import RunningMeanStd

STD_FLOOR = 1e-3
"""Smallest standard deviation divided by: a value that never moved (a sensor constant on the
tracks seen so far) is centred, not blown up by 1/0, when it first moves."""
CLIP = 10.0
"""Normalised values are clipped to +-this (SB3's ``clip_obs``): one observation far outside
everything seen so far cannot saturate the first layer."""
PRIOR_COUNT = 1e-12
"""The weight of ``RunningMeanStd``'s prior (mean 0, variance 1): Gymnasium's default of 1e-4
would bias a variance of 1e-4 (a scaled sensor that barely moves) by ~0.1 % after 1 000
observations; this leaves the statistics those of the observations."""


class RunningObsNorm:
    """Per-value running mean and variance of observations, and the affine map they give."""

    def __init__(self, obs_dim: int, device: torch.device) -> None:
        self.obs_dim = int(obs_dim)
        self._stats = RunningMeanStd(epsilon=PRIOR_COUNT, shape=(self.obs_dim,))
        self._shift_np = np.zeros(self.obs_dim, np.float32)
        self._scale_np = np.ones(self.obs_dim, np.float32)
        self._shift = torch.zeros(self.obs_dim, dtype=torch.float32, device=device)
        self._scale = torch.ones(self.obs_dim, dtype=torch.float32, device=device)

    # --- statistics ---------------------------------------------------------------------------
    def update(self, observations: np.ndarray) -> None:
        """Count ``observations`` ``(k, obs_dim)`` (Chan et al.'s merge of their mean and
        variance into the running ones), then refresh the map."""
        x = np.asarray(observations, np.float64).reshape(-1, self.obs_dim)
        if len(x) == 0:
            return
        self._stats.update(x)
        self._refresh()

    @property
    def count(self) -> int:
        """Observations counted so far (the statistics' count less the prior's weight)."""
        return round(self._stats.count - PRIOR_COUNT)

    @property
    def mean(self) -> np.ndarray:
        return np.array(self._stats.mean, np.float64)

    @property
    def std(self) -> np.ndarray:
        """The population standard deviation of the counted observations (0 before any)."""
        return np.sqrt(self._stats.var) if self.count else np.zeros(self.obs_dim)

    def _refresh(self) -> None:
        self._shift_np = self.mean.astype(np.float32)
        self._scale_np = (1.0 / np.maximum(self.std, STD_FLOOR)).astype(np.float32)
        self._shift.copy_(torch.from_numpy(self._shift_np))
        self._scale.copy_(torch.from_numpy(self._scale_np))

    # --- the map ------------------------------------------------------------------------------
    def apply(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` ``(..., obs_dim)`` or ``(batch, w * obs_dim)`` standardised and clipped; ``x``
        itself before any observation is counted."""
        if self.count == 0:
            return x
        shape = x.shape
        z = (x.reshape(*shape[:-1], -1, self.obs_dim) - self._shift) * self._scale
        return z.clamp_(-CLIP, CLIP).reshape(shape)

    def apply_np(self, x: np.ndarray) -> np.ndarray:
        """:meth:`apply` on a NumPy array (the acting step's window), float32."""
        if self.count == 0:
            return x
        shape = x.shape
        z = (np.asarray(x, np.float32).reshape(-1, self.obs_dim) - self._shift_np) * self._scale_np
        return np.clip(z, -CLIP, CLIP, out=z).reshape(shape)

    # --- state --------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Tensors and plain values only (checkpoints load with ``weights_only``)."""
        var = np.array(self._stats.var, np.float64)
        return {"count": float(self._stats.count), "mean": torch.from_numpy(self.mean),
                "var": torch.from_numpy(var)}  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        mean = state["mean"].detach().cpu().numpy().astype(np.float64)
        var = state["var"].detach().cpu().numpy().astype(np.float64)
        if mean.shape != (self.obs_dim,) or var.shape != (self.obs_dim,):
            raise ValueError(f"observation statistics of {mean.shape} for {self.obs_dim} values")
        self._stats.mean, self._stats.var = mean, var
        self._stats.count = float(state["count"])
        self._refresh()
