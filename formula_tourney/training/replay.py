"""Replay a test drive of a trained actor: the very drive a test made, its laps, and a GIF.

``formula-tourney replay CHECKPOINT [--track T] [--start-s-m S] [--grip G] [--seed N]``
drives the checkpoint's actor with ``training.evaluate.run_test_episode``, the one function the
tests of a run drive with, on the test env ``training.envs.RunEnvs`` builds from the
checkpoint's run spec, from the start, at the grip and with the seed of a ``tests.parquet``
row: so it drives the laps that row recorded, to the step. ``--best JOB`` takes those from
the job's tests: the run's best clean lap as every table computes it (``results.metrics``), and
the checkpoint that drove it. Replay starting at the line instead of the test's start drove
another lap than the table's (a 78.82 s lap from 1 635 m became no timed lap at all).

``--trace FILE`` (``.csv`` or ``.parquet``) writes every step of the drive (time, distance,
position on the track, speed, steer and pedals, laps) for reading where a drive is lost: a
crash shows as the steps before it (how fast the car met the corner, where it braked).
``--braking`` reads that for every braking zone of the run's reference line
(``training.braking``): where the drive first braked and how fast, against where and how fast
the QSS lap on that line brakes.

The GIF shows the best clean lap of the drive (the whole drive when it has none) in the race
GIF's look (``sim.multicar.frames``): the track drawn once, the car stamped large enough to see
with the line it has driven so far, and a column with the lap, its running time and the speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from formula_tourney.errors import UserInputError
from formula_tourney.results import metrics
from formula_tourney.results.folder import JobFolder
from formula_tourney.results.layout import BEST_CHECKPOINT, CHECKPOINTS_DIR
from formula_tourney.safeio import atomic_write_parquet, atomic_write_text
from formula_tourney.sim.draw import MIN_CAR_PX, TrackRenderer
from formula_tourney.sim.multicar.frames import (
    COLUMN_PX,
    DIM_RGB,
    PALETTE,
    PANEL_RGB,
    TEXT_RGB,
    write_video,
)
from formula_tourney.sim.track import Track
from formula_tourney.training.braking import drive_braking, line_braking_zones
from formula_tourney.training.checkpoint import load_run_checkpoint
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.evaluate import (
    DriveResult,
    check_observation_size,
    drive_seed,
    run_test_episode,
    start_positions,
)
from formula_tourney.training.run_spec import RunSpec

CAR_PX = 2.0 * MIN_CAR_PX
"""Least length of the replayed car in pixels: one car alone must be seen at a glance."""
SIZE_PX = 480
"""The track's drawing, as in the race GIF."""
START_MATCH_M = 1e-6
"""A start within this of one of the run's test starts is that start (its seed follows)."""


@dataclass(frozen=True)
class DriveChoice:
    """Which test drive to replay: a test row's checkpoint, track, start and grip (None: the
    run's own grip), and the lap the table shows for it where known."""

    checkpoint: Path
    track: str
    start_s_m: float
    grip_scale: float | None = None
    episode: int | None = None
    table_lap_s: float = math.nan


def _job_checkpoint(folder: JobFolder, rel: str, spec: RunSpec, track: str,
                    episode: int) -> Path:
    """The checkpoint of a test round: the row's own (``save_test_checkpoints``), else
    best.pt, which holds the round of the best lap on the run's key track."""
    if rel:
        return folder.path / rel
    if track == spec.key_track:
        return folder.checkpoint_path(BEST_CHECKPOINT)
    raise UserInputError(
        f"{folder.path}: the actor of episode {episode}'s test on {track} was not kept "
        f"({CHECKPOINTS_DIR}/{BEST_CHECKPOINT} holds the best on {spec.key_track}); train with "
        "--save-test-checkpoints to replay tests on other tracks")


def best_test(job_dir: str | Path, track: str | None = None) -> DriveChoice:
    """The test drive that made the run's best clean lap on ``track`` (default: its key
    track), found as the tables find it: ``results.metrics`` on the tests at the run's grip."""
    folder = JobFolder(Path(job_dir))
    try:
        spec = RunSpec.from_json(folder.config(), str(folder.config_path))
    except FileNotFoundError:
        raise UserInputError(f"{job_dir}: not a job folder (no config.json)") from None
    track = track or spec.key_track
    tests = folder.tests()
    tested = sorted(set(tests["track"].astype(str))) if not tests.empty else []
    tests = tests.loc[tests["track"].astype(str) == track] if not tests.empty else tests
    if tests.empty:
        raise UserInputError(f"{job_dir}: no test on {track!r}; tested on: "
                             f"{', '.join(tested) or 'nothing yet'}")
    runs = metrics.run_table(metrics.model_table(tests.assign(job_id=str(job_dir))))
    lap_s = float(runs["run_best_s"].iloc[0])
    if not math.isfinite(lap_s):
        raise UserInputError(f"{job_dir}: no clean lap on {track} in its tests: nothing to replay")
    episode = int(runs["best_episode"].iloc[0])
    test_round = tests.loc[tests["episode"] == episode]
    row = test_round.loc[test_round["best_lap_s"] == lap_s].iloc[0]
    return DriveChoice(
        checkpoint=_job_checkpoint(folder, str(row["checkpoint"] or ""), spec, track, episode),
        track=track, start_s_m=float(row["start_s_m"]), grip_scale=float(row["grip_scale"]),
        episode=episode, table_lap_s=lap_s)


def seed_for_start(spec: RunSpec, length_m: float, start_s_m: float) -> int:
    """The seed the run's tests drove ``start_s_m`` with (``evaluate.drive_seed``); a start
    that is none of the run's test starts gets the first start's."""
    starts = start_positions(length_m, spec.schedule.test_starts)
    index = next((k for k, s in enumerate(starts) if abs(s - start_s_m) <= START_MATCH_M), 0)
    return drive_seed(spec.seed, index)


TRACE_SUFFIXES = (".csv", ".parquet")
"""What ``--trace`` writes: a table of the drive's steps, for a spreadsheet or for pandas."""


def write_trace(path: Path, steps: Any) -> Path:
    """Every step of a drive (``DriveResult.steps_trace``) to ``path``, CSV or Parquet by its
    suffix, atomically."""
    if path.suffix.lower() == ".parquet":
        return atomic_write_parquet(path, steps)
    return atomic_write_text(path, steps.to_csv(index=False, float_format="%.6g"))


def replay(checkpoint: str | Path, track: str | None = None, gif: str | Path | None = None, *,
           start_s_m: float | None = None, grip_scale: float | None = None,
           seed: int | None = None, max_steps: int | None = None, frame_every: int = 2,
           device: str = "cpu", episode: int | None = None,
           trace: str | Path | None = None, braking: bool = False) -> dict[str, Any]:
    """Drive one test of the checkpoint's actor as the run's tests drive it; returns its laps.

    Defaults are the run's: its key track, its first test start (50 m before the line), its
    grip, the seed its tests use at that start and its ``test_max_steps``. ``gif`` (optional)
    gets the best clean lap of the drive, or the whole drive when it has none. ``episode``:
    the test round the checkpoint must hold (a test row's), refused before driving otherwise.
    ``trace`` (optional, ``.csv`` or ``.parquet``) gets every step of the drive; ``braking``
    adds where it braked for each braking zone of the run's reference line
    (``training.braking``).
    """
    checkpoint = Path(checkpoint)
    if gif is not None and Path(gif).suffix.lower() != ".gif":
        raise UserInputError(f"--gif {gif}: the file name must end in .gif")
    if trace is not None and Path(trace).suffix.lower() not in TRACE_SUFFIXES:
        raise UserInputError(f"--trace {trace}: the file name must end in "
                             f"{' or '.join(TRACE_SUFFIXES)}")
    if frame_every < 1 or (max_steps is not None and max_steps < 1):
        raise UserInputError("replay: --frame-every and --max-steps must be >= 1")
    if not checkpoint.is_file():
        raise UserInputError(f"checkpoint {checkpoint} does not exist")
    agent, spec, extra = load_run_checkpoint(checkpoint, device=device)
    if episode is not None and "episode" in extra and extra["episode"] != episode:
        raise UserInputError(f"{checkpoint} holds the actor of episode {extra.get('episode')}, "
                             f"not episode {episode}'s")
    track = track or spec.key_track
    envs = RunEnvs(spec, extra_tracks=[track])
    length_m = envs.tracks[track].length_m
    start = start_positions(length_m, spec.schedule.test_starts)[0] if start_s_m is None \
        else float(start_s_m)
    seed = seed_for_start(spec, length_m, start) if seed is None else int(seed)
    env = envs.make(track, test=True, max_steps=max_steps, grip_scale=grip_scale)
    try:
        check_observation_size(env, agent, checkpoint)
        drive = run_test_episode(agent, env, track, start, seed=seed,
                                 keep_steps=gif is not None or trace is not None or braking)
    finally:
        env.close()
    summary: dict[str, Any] = {
        "checkpoint": str(checkpoint), "episode": extra.get("episode"), "track": track,
        "reference": spec.reference, "start_s_m": start, "grip_scale": drive.grip_scale,
        "seed": seed, "lap_times_s": drive.lap_times_s, "lap_damage": drive.lap_damage,
        "best_lap_s": None if math.isnan(drive.best_lap_s) else drive.best_lap_s,
        "termination": drive.termination, "steps": drive.steps, "damage": drive.damage,
        "reward": drive.reward, "gif": None, "frames": 0, "trace": None, "braking": None,
    }
    if braking:
        zones = line_braking_zones(envs.tracks[track], envs.line_offsets(track),
                                   spec.env.car_params(), drive.grip_scale)  # fmt: skip
        summary["braking"] = [z.as_dict() for z in drive_braking(
            drive.steps_trace, start, length_m, zones, drive.termination)]
    if trace is not None:
        summary["trace"] = str(write_trace(Path(trace), drive.steps_trace))
    if gif is not None:
        title = f"{spec.variant} seed {spec.seed}" + (
            f", episode {extra['episode']}" if extra.get("episode") is not None else "")
        frames = LapFrames(envs.tracks[track], spec, frame_every).draw(drive, title, seed)
        fps = 1.0 / (spec.env.control_period_s * frame_every)
        summary.update(gif=str(write_video(Path(gif), frames, fps)), frames=len(frames))
    return summary


class LapFrames:
    """The frames of one drive: the race GIF's track drawing and column, one car."""

    def __init__(self, track: Track, spec: RunSpec, every: int) -> None:
        self.renderer = TrackRenderer(track, size_px=SIZE_PX)
        self.car = spec.env.car_params()
        self.every = max(int(every), 1)
        self.font = ImageFont.load_default()

    def draw(self, drive: DriveResult, title: str, seed: int) -> list[np.ndarray]:
        """The best clean lap (time from its start), else every step of the drive."""
        lap = drive.best_trace is not None
        trace = drive.best_trace if lap else drive.steps_trace
        if trace is None or trace.empty:
            raise UserInputError("replay: the drive took no step to draw")
        if lap:
            number = 1 + next(i for i, (t, d) in enumerate(zip(
                drive.lap_times_s, drive.lap_damage, strict=True))
                if d <= 0.0 and t == drive.best_lap_s)
            heading = f"Lap {number} of the drive (clean)"
        else:
            heading = f"No clean lap: {drive.termination}"
        facts = [title, f"{drive.track} from {drive.start_s_m:.0f} m",
                 f"grip {drive.grip_scale:.2f}  seed {seed}"]
        keep = list(range(0, len(trace), self.every))
        if keep[-1] != len(trace) - 1:
            keep.append(len(trace) - 1)
        x, y = trace["x_m"].to_numpy(float), trace["y_m"].to_numpy(float)
        psi = np.arctan2(np.gradient(y), np.gradient(x)) if len(trace) > 1 else np.zeros(1)
        cols, rows = self.renderer.to_px(x, y)
        frames = []
        for i in keep:
            last = i == len(trace) - 1
            clock = drive.best_lap_s if lap and last else float(trace["time_s"].iloc[i])
            status = ([f"Lap time {clock:7.3f} s" if lap else f"Time {clock:7.1f} s",
                       f"Speed {float(trace['speed_kmh'].iloc[i]):5.0f} km/h"]
                      + ([] if lap else [f"Laps {int(trace['laps'].iloc[i])}"]))
            img = self._track(cols[:i + 1], rows[:i + 1], float(psi[i]))
            frames.append(self._with_column(img, heading, status, facts, done=lap and last))
        return frames

    def _track(self, cols: np.ndarray, rows: np.ndarray, psi: float) -> np.ndarray:
        """The track with the line driven so far and the car at its end."""
        tr = self.renderer
        colour = PALETTE[0]
        canvas = Image.fromarray(tr.background)
        if len(cols) > 1:
            ImageDraw.Draw(canvas).line(list(zip(cols.tolist(), rows.tolist(), strict=True)),
                                        fill=tuple(int(0.6 * c) for c in colour), width=2)
        img = np.array(canvas)
        length_px = max(self.car.car_length_m * tr.scale, CAR_PX)
        width_px = max(self.car.car_width_m * tr.scale, CAR_PX * 0.45)
        tr._stamp(img, float(cols[-1]), float(rows[-1]), psi, length_px, width_px, colour)
        return img

    def _with_column(self, img: np.ndarray, heading: str, status: list[str], facts: list[str],
                     done: bool) -> np.ndarray:
        """The race GIF's column (``sim.multicar.frames``) beside the track: the lap, its
        running time and speed, then which test this is."""
        panel = Image.new("RGB", (COLUMN_PX, img.shape[0]), PANEL_RGB)
        draw = ImageDraw.Draw(panel)
        draw.rectangle((10, 10, 20, 18), fill=PALETTE[0])
        draw.text((26, 8), heading, fill=TEXT_RGB, font=self.font)
        y = 30
        for line in status:
            draw.text((10, y), line + ("  (timed)" if done and line.startswith("Lap") else ""),
                      fill=TEXT_RGB, font=self.font)
            y += 16
        y += 8
        for line in facts:
            draw.text((10, y), line, fill=DIM_RGB, font=self.font)
            y += 16
        return np.concatenate([img, np.asarray(panel)], axis=1)


def replay_best(job_dir: str | Path, track: str | None = None, gif: str | Path | None = None,
                **options: Any) -> dict[str, Any]:
    """Replay the test that made the run's best clean lap on ``track`` (``best_test``); the
    summary adds the table's lap, the test's round, and whether the replay drove that lap to
    the millisecond."""
    choice = best_test(job_dir, track)
    summary = replay(choice.checkpoint, choice.track, gif, start_s_m=choice.start_s_m,
                     grip_scale=choice.grip_scale, episode=choice.episode, **options)
    lap = summary["best_lap_s"]
    summary.update(table_lap_s=choice.table_lap_s,
                   reproduced=lap is not None and abs(lap - choice.table_lap_s) < 5e-4)
    return summary
