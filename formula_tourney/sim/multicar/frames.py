"""Race frames: every car on the track in its own colour, and a live standings column.

The track comes from :class:`sim.draw.TrackRenderer` (drawn once with Agg; cars stamped with
NumPy), the column is drawn with Pillow's default bitmap font, so rendering needs no display and
no font files. Frames are kept every ``every`` steps (default 2: a 5-lap race on `flowing` is
~1,000 frames of ~0.5 MB otherwise).
"""

from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write
from formula_tourney.sim import kernels as K
from formula_tourney.sim.draw import BACKGROUND_RGB, MIN_CAR_PX, TrackRenderer
from formula_tourney.sim.multicar import lockstep_kernels as RK
from formula_tourney.sim.track import Track

PALETTE = ((220, 30, 30), (30, 90, 230), (240, 200, 20), (200, 40, 200), (20, 200, 200),
           (250, 130, 20), (120, 230, 80), (250, 250, 250), (150, 90, 40), (120, 120, 250),
           (250, 150, 190), (60, 60, 60))
COLUMN_PX = 260
PANEL_RGB = (24, 26, 30)
TEXT_RGB = (235, 235, 235)
DIM_RGB = (140, 140, 140)


class RaceRenderer:
    """``frame(sim, timing, race_time_s)`` -> an RGB array (or None between kept frames)."""

    def __init__(self, track: Track, names: list[str], grass_width_m: float = 5.0,
                 size_px: int = 480, every: int = 2) -> None:
        self.track_renderer = TrackRenderer(track, grass_width_m, size_px)
        self.names = list(names)
        self.every = max(int(every), 1)
        self._calls = 0
        self._font = ImageFont.load_default()

    def frame(self, sim: Any, timing: Any, race_time_s: float) -> np.ndarray | None:
        self._calls += 1
        if (self._calls - 1) % self.every:
            return None
        tr = self.track_renderer
        img = tr.background.copy()
        car = sim.car
        length_px = max(car.car_length_m * tr.scale, MIN_CAR_PX)
        width_px = max(car.car_width_m * tr.scale, MIN_CAR_PX * 0.45)
        for c in range(sim.n):
            if sim.mode[c] == RK.MODE_OUT:
                continue
            st = sim.state[c]
            cx, cy = tr.to_px(st[K.ST_X], st[K.ST_Y])
            # The track renderer's own car stamp (a pointed wedge), in this car's colour.
            tr._stamp(img, float(cx), float(cy), float(st[K.ST_PSI]), length_px, width_px,
                      PALETTE[c % len(PALETTE)])
        need = 40 + 16 * sim.n
        if img.shape[0] < need:  # a flat track: room for every line of the standings
            pad = np.empty((need - img.shape[0], img.shape[1], 3), dtype=np.uint8)
            pad[:] = BACKGROUND_RGB
            img = np.concatenate([img, pad], axis=0)
        return np.concatenate([img, self._column(timing, race_time_s, img.shape[0])], axis=1)

    def _column(self, timing: Any, race_time_s: float, height_px: int) -> np.ndarray:
        panel = Image.new("RGB", (COLUMN_PX, height_px), PANEL_RGB)
        draw = ImageDraw.Draw(panel)
        lead = timing.cars[timing.leader()]
        lap = min(lead.laps_done + 1, timing.laps)
        draw.text((10, 8), f"Lap {lap}/{timing.laps}   {max(race_time_s, 0.0):6.1f} s",
                  fill=TEXT_RGB, font=self._font)
        y = 30
        for pos, c in enumerate(timing.order(), start=1):
            car = timing.cars[c]
            draw.rectangle((10, y + 2, 20, y + 10), fill=PALETTE[c % len(PALETTE)])
            if car.status == "retired":
                tail, colour = "out", DIM_RGB
            elif pos == 1:
                tail, colour = "leader" if car.status == "running" else "winner", TEXT_RGB
            elif timing.laps_behind(c) > 0:
                tail, colour = f"+{timing.laps_behind(c)}L", TEXT_RGB
            else:
                gap = timing.gap_s(c)
                tail, colour = (f"+{gap:.1f}" if math.isfinite(gap) else ""), TEXT_RGB
            if car.status == "finished":
                tail += " F"
            draw.text((26, y), f"{pos:>2} {_short(self.names[c]):<22} {tail}", fill=colour,
                      font=self._font)
            y += 16
            if y > height_px - 16:
                break
        return np.asarray(panel)


def _short(name: str, width: int = 22) -> str:
    """A name that fits the column, its end kept (``WIN1-x-small/seed-1`` differ there)."""
    return name if len(name) <= width else name[:8] + "~" + name[-(width - 9):]


def write_video(path: Path, frames: list[np.ndarray | None], fps: int) -> Path:
    """Frames -> ``.gif`` (Pillow) or ``.mp4`` (ffmpeg through a pipe), written atomically."""
    kept = [f for f in frames if f is not None]
    if not kept:
        raise UserInputError(f"{path}: no frames were rendered")
    if path.suffix.lower() == ".gif":
        images = [Image.fromarray(f).convert("P", palette=Image.Palette.ADAPTIVE) for f in kept]

        def write_gif(tmp: Path) -> None:
            images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                           duration=max(int(round(1000 / fps)), 20), loop=0)
        return atomic_write(path, write_gif)
    ffmpeg = ffmpeg_path()
    if ffmpeg is None:
        raise UserInputError(f"{path}: writing MP4 needs ffmpeg on the PATH")
    h, w = kept[0].shape[:2]

    def write_mp4(tmp: Path) -> None:
        cmd = [ffmpeg, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
               "-s", f"{w}x{h}", "-r", str(fps), "-i", "-", "-vf",
               "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-f", "mp4", str(tmp)]
        proc = subprocess.run(cmd, input=b"".join(np.ascontiguousarray(f).tobytes()
                                                  for f in kept), capture_output=True)
        if proc.returncode != 0:
            raise UserInputError(f"{path}: ffmpeg failed: {proc.stderr.decode()[:200]}")
    return atomic_write(path, write_mp4)


def ffmpeg_path() -> str | None:
    """The ffmpeg executable, or None (MP4 output is then refused before the race runs)."""
    return shutil.which("ffmpeg")
