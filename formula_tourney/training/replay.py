"""Replay a trained actor for one lap and write it as an animated GIF.

``formula-tourney replay CHECKPOINT --track T --gif F``: the checkpoint's run spec says which
reference line, LAC and env settings the actor was trained with; the env is built the same way
(``training.envs``), run greedily
(no exploration) from the default start until one timed lap is complete or the episode ends, and
its ``rgb_array`` frames are written with Pillow.
"""

from __future__ import annotations

import io
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write_bytes
from formula_tourney.training.checkpoint import load_run_checkpoint
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.evaluate import check_observation_size

Policy = Callable[[np.ndarray], np.ndarray]
"""Greedy action for an observation window of shape (window, obs_dim)."""


def record_lap(env: Any, policy: Policy, window: int = 1, max_steps: int = 3000,
               frame_every: int = 1, laps: int = 1, seed: int = 0) -> dict[str, Any]:
    """Drive ``env`` with ``policy`` until ``laps`` timed laps are done or the episode ends.

    The observation window is padded at the start by repeating the first observation, so a
    windowed actor sees a full window from the first step. Returns the frames (every
    ``frame_every``-th control step, plus the last) and how the run ended.
    """
    if window < 1 or frame_every < 1 or max_steps < 1:
        raise UserInputError("replay: window, frame_every and max_steps must be >= 1")
    obs, info = env.reset(seed=seed)
    history: deque[np.ndarray] = deque([np.asarray(obs, dtype=np.float32)] * window,
                                       maxlen=window)
    frames = [env.render()]
    steps, reward_sum, ending = 0, 0.0, "max_steps"
    for steps in range(1, max_steps + 1):  # noqa: B007 (steps is reported after the loop)
        action = np.asarray(policy(np.stack(history)), dtype=np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        reward_sum += float(reward)
        history.append(np.asarray(obs, dtype=np.float32))
        done_laps = int(info.get("laps", 0))
        if steps % frame_every == 0 or terminated or truncated or done_laps >= laps:
            frames.append(env.render())
        if done_laps >= laps:
            ending = "lap"
            break
        if terminated or truncated:
            ending = str(info.get("termination") or ("terminated" if terminated else "truncated"))
            break
    frames = [f for f in frames if f is not None]
    return {
        "frames": frames, "steps": steps, "reward": reward_sum, "ending": ending,
        "lap_times_s": [float(t) for t in info.get("lap_times_s", [])],
        "damage": float(info.get("damage", 0.0)),
    }


def write_gif(frames: list[np.ndarray], path: str | Path, frame_duration_ms: float,
              max_width: int = 640) -> Path:
    """Frames (H, W, 3 uint8) -> animated GIF, downscaled to ``max_width`` to keep files small."""
    if not frames:
        raise UserInputError("replay: the env rendered no frames (does it support rgb_array?)")
    images = []
    for frame in frames:
        img = Image.fromarray(np.asarray(frame, dtype=np.uint8)).convert("RGB")
        if img.width > max_width:
            img = img.resize((max_width, round(img.height * max_width / img.width)))
        images.append(img.convert("P", palette=Image.Palette.ADAPTIVE))
    buf = io.BytesIO()
    images[0].save(buf, format="GIF", save_all=True, append_images=images[1:],
                   duration=max(int(round(frame_duration_ms)), 20), loop=0)
    return atomic_write_bytes(path, buf.getvalue())


def replay(checkpoint: str | Path, track: str, gif: str | Path, max_steps: int = 3000,
           frame_every: int = 2, laps: int = 1, device: str = "cpu") -> dict[str, Any]:
    """Load the actor, drive ``laps`` laps on ``track`` and write ``gif``; returns a summary.

    The env comes from the checkpoint's run spec through ``training.envs.RunEnvs``, the same
    path training and ``eval`` take, so the replay drives the line the actor learned.
    """
    checkpoint = Path(checkpoint)
    gif = Path(gif)
    if gif.suffix.lower() != ".gif":
        raise UserInputError(f"--gif {gif}: the file name must end in .gif")
    if not checkpoint.is_file():
        raise UserInputError(f"checkpoint {checkpoint} does not exist")
    agent, spec, _extra = load_run_checkpoint(checkpoint, device=device)
    envs = RunEnvs(spec, extra_tracks=[track])
    env = envs.make(track, test=True, max_steps=max_steps, render_mode="rgb_array")
    try:
        check_observation_size(env, agent, checkpoint)
        result = record_lap(env, agent.act, window=agent.actor_window, max_steps=max_steps,
                            frame_every=frame_every, laps=laps)
    finally:
        env.close()
    path = write_gif(result["frames"], gif, 1000.0 * spec.env.control_period_s * frame_every)
    summary = {k: v for k, v in result.items() if k != "frames"}
    summary.update(gif=str(path), frames=len(result["frames"]), track=track,
                   checkpoint=str(checkpoint), reference=spec.reference)
    return summary
