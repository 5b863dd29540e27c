"""Top-down ``rgb_array`` frames of a track and its cars, headless.

The track (grass, asphalt, walls, start line) is drawn once with matplotlib's Agg backend into an
array; each frame copies it and stamps the cars as filled polygons with NumPy (~0.1 ms a frame).
highway-env's viewer would need pygame and its own road-network objects, and it opens a window
unless SDL is told to use a dummy driver; Agg needs no display and no extra dependency.
"""

from __future__ import annotations

import numpy as np

from formula_tourney.sim import kernels as K
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.track import Track

GRASS_RGB = (96, 160, 72)
ASPHALT_RGB = (90, 90, 96)
BACKGROUND_RGB = (40, 48, 40)
WALL_RGB = (230, 230, 230)
START_RGB = (250, 250, 250)
CAR_RGB = ((220, 30, 30), (30, 90, 230), (240, 200, 20), (200, 40, 200))
MIN_CAR_PX = 9.0
"""Cars are drawn at least this long so they stay visible on a 5 km track."""


class TrackRenderer:
    """Draws one track once; :meth:`frame` adds the cars of a state array."""

    def __init__(self, track: Track, grass_width_m: float = 5.0, size_px: int = 600):
        self.track = track
        self.grass_width_m = float(grass_width_m)
        nx, ny = -np.sin(track.heading_rad), np.cos(track.heading_rad)
        wl = track.width_left_m + self.grass_width_m
        wr = track.width_right_m + self.grass_width_m
        lx, ly = track.x_m + wl * nx, track.y_m + wl * ny
        rx, ry = track.x_m - wr * nx, track.y_m - wr * ny
        pad = 10.0
        xmin = min(lx.min(), rx.min()) - pad
        xmax = max(lx.max(), rx.max()) + pad
        ymin = min(ly.min(), ry.min()) - pad
        ymax = max(ly.max(), ry.max()) + pad
        self.scale = size_px / max(xmax - xmin, ymax - ymin)
        self.width = max(int(round((xmax - xmin) * self.scale)), 16)
        self.height = max(int(round((ymax - ymin) * self.scale)), 16)
        self.xmin, self.ymin = xmin, ymin
        self.background = self._draw_background(nx, ny)

    def to_px(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World metres to pixel column/row (row 0 at the top)."""
        return (np.asarray(x) - self.xmin) * self.scale, \
            self.height - (np.asarray(y) - self.ymin) * self.scale

    def _draw_background(self, nx: np.ndarray, ny: np.ndarray) -> np.ndarray:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.patches import PathPatch
        from matplotlib.path import Path

        tr = self.track
        dpi = 100
        fig = Figure(figsize=(self.width / dpi, self.height / dpi), dpi=dpi)
        canvas = FigureCanvasAgg(fig)
        ax = fig.add_axes((0, 0, 1, 1))
        ax.set_axis_off()
        ax.set_xlim(self.xmin, self.xmin + self.width / self.scale)
        ax.set_ylim(self.ymin, self.ymin + self.height / self.scale)
        fig.patch.set_facecolor(np.array(BACKGROUND_RGB) / 255)

        def ring(wl: np.ndarray, wr: np.ndarray) -> Path:
            # Outer loop one way, inner loop the other: the nonzero rule leaves the infield open.
            left = np.c_[tr.x_m + wl * nx, tr.y_m + wl * ny]
            right = np.c_[tr.x_m - wr * nx, tr.y_m - wr * ny][::-1]
            verts = np.vstack([left, left[:1], right, right[:1]])
            codes = np.full(len(verts), Path.LINETO)
            codes[0] = codes[len(left) + 1] = Path.MOVETO
            codes[len(left)] = codes[-1] = Path.CLOSEPOLY
            return Path(verts, codes)

        g = self.grass_width_m
        for path, rgb in ((ring(tr.width_left_m + g, tr.width_right_m + g), GRASS_RGB),
                          (ring(tr.width_left_m, tr.width_right_m), ASPHALT_RGB)):
            ax.add_patch(PathPatch(path, facecolor=np.array(rgb) / 255, edgecolor="none"))
        for sign, w in ((1.0, tr.width_left_m + g), (-1.0, tr.width_right_m + g)):
            xs = np.append(tr.x_m + sign * w * nx, tr.x_m[0] + sign * w[0] * nx[0])
            ys = np.append(tr.y_m + sign * w * ny, tr.y_m[0] + sign * w[0] * ny[0])
            ax.plot(xs, ys, color=np.array(WALL_RGB) / 255, linewidth=1.0)
        ax.plot([tr.x_m[0] + tr.width_left_m[0] * nx[0], tr.x_m[0] - tr.width_right_m[0] * nx[0]],
                [tr.y_m[0] + tr.width_left_m[0] * ny[0], tr.y_m[0] - tr.width_right_m[0] * ny[0]],
                color=np.array(START_RGB) / 255, linewidth=2.0)
        canvas.draw()
        rgba = np.asarray(canvas.buffer_rgba())
        return np.ascontiguousarray(rgba[:self.height, :self.width, :3])

    def frame(self, state: np.ndarray, car: CarParams | None = None) -> np.ndarray:
        """An ``(H, W, 3)`` uint8 image of the track with every car of ``state`` on it."""
        car = car or CarParams()
        img = self.background.copy()
        length_px = max(car.car_length_m * self.scale, MIN_CAR_PX)
        width_px = max(car.car_width_m * self.scale, MIN_CAR_PX * 0.45)
        for c in range(state.shape[0]):
            st = state[c]
            cx, cy = self.to_px(st[K.ST_X], st[K.ST_Y])
            self._stamp(img, float(cx), float(cy), float(st[K.ST_PSI]), length_px, width_px,
                        CAR_RGB[c % len(CAR_RGB)])
        return img

    def _stamp(self, img: np.ndarray, cx: float, cy: float, psi: float, length_px: float,
               width_px: float, rgb: tuple[int, int, int]) -> None:
        """Fill a car-shaped wedge (pointed nose) centred at pixel ``(cx, cy)``."""
        h, w = img.shape[:2]
        r = int(np.ceil(0.5 * max(length_px, width_px))) + 1
        x0, x1 = max(int(cx) - r, 0), min(int(cx) + r + 1, w)
        y0, y1 = max(int(cy) - r, 0), min(int(cy) + r + 1, h)
        if x0 >= x1 or y0 >= y1:
            return
        yy, xx = np.mgrid[y0:y1, x0:x1]
        dx, dy = xx + 0.5 - cx, -(yy + 0.5 - cy)  # image rows grow downwards
        c, s = np.cos(psi), np.sin(psi)
        along = dx * c + dy * s
        across = -dx * s + dy * c
        half_l, half_w = 0.5 * length_px, 0.5 * width_px
        # Width tapers towards the nose so the heading is visible even at a few pixels.
        taper = np.clip((half_l - along) / (0.6 * length_px), 0.0, 1.0)
        inside = (np.abs(along) <= half_l) & (np.abs(across) <= half_w * taper)
        img[y0:y1, x0:x1][inside] = rgb
