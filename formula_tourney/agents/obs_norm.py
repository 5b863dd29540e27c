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
float64), so a run gives the same statistics whatever the number of cars or the update order.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

STD_FLOOR = 1e-3
"""Smallest standard deviation divided by: a value that never moved (a sensor constant on the
tracks seen so far) is centred, not blown up by 1/0, when it first moves."""
CLIP = 10.0
"""Normalised values are clipped to +-this (SB3's ``clip_obs``): one observation far outside
everything seen so far cannot saturate the first layer."""


class RunningObsNorm:
    """Per-value running mean and variance of observations, and the affine map they give."""

    def __init__(self, obs_dim: int, device: torch.device) -> None:
        self.obs_dim = int(obs_dim)
        self.count = 0
        self._mean = np.zeros(self.obs_dim, np.float64)
        self._m2 = np.zeros(self.obs_dim, np.float64)  # sum of squared deviations from the mean
        self._shift_np = np.zeros(self.obs_dim, np.float32)
        self._scale_np = np.ones(self.obs_dim, np.float32)
        self._shift = torch.zeros(self.obs_dim, dtype=torch.float32, device=device)
        self._scale = torch.ones(self.obs_dim, dtype=torch.float32, device=device)

    # --- statistics ---------------------------------------------------------------------------
    def update(self, observations: np.ndarray) -> None:
        """Count ``observations`` ``(k, obs_dim)``: Chan et al.'s merge of their mean and squared
        deviations into the running ones, then the map is refreshed."""
        x = np.asarray(observations, np.float64).reshape(-1, self.obs_dim)
        k = len(x)
        if k == 0:
            return
        batch_mean = x.mean(axis=0)
        batch_m2 = np.square(x - batch_mean).sum(axis=0)
        total = self.count + k
        delta = batch_mean - self._mean
        self._mean = self._mean + delta * (k / total)
        self._m2 = self._m2 + batch_m2 + np.square(delta) * (self.count * k / total)
        self.count = total
        self._refresh()

    @property
    def mean(self) -> np.ndarray:
        return self._mean.copy()

    @property
    def std(self) -> np.ndarray:
        """The population standard deviation of the counted observations (0 before any)."""
        return np.sqrt(self._m2 / self.count) if self.count else np.zeros(self.obs_dim)

    def _refresh(self) -> None:
        self._shift_np = self._mean.astype(np.float32)
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
        return {"count": self.count, "mean": torch.from_numpy(self._mean.copy()),
                "m2": torch.from_numpy(self._m2.copy())}  # fmt: skip

    def load_state_dict(self, state: dict[str, Any]) -> None:
        mean = state["mean"].detach().cpu().numpy().astype(np.float64)
        m2 = state["m2"].detach().cpu().numpy().astype(np.float64)
        if mean.shape != (self.obs_dim,) or m2.shape != (self.obs_dim,):
            raise ValueError(f"observation statistics of {mean.shape} for {self.obs_dim} values")
        self.count, self._mean, self._m2 = int(state["count"]), mean, m2
        self._refresh()
