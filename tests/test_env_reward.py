"""The reward model: its table, the kernel's packing derived from it, ``info["rewards"]``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from simtracks import stadium

from formula_tourney.agents.variants import AgentConfig
from formula_tourney.errors import UserInputError
from formula_tourney.field_marks import added_in_layout, beyond_paper
from formula_tourney.lines.limit import reference_limit_s
from formula_tourney.lines.registry import reference_offsets
from formula_tourney.lines.speed_profile import speed_profile
from formula_tourney.sim import kernels as K
from formula_tourney.sim import reward as R
from formula_tourney.sim.config import EnvSettings
from formula_tourney.sim.env import FormulaRacingEnv, FormulaRacingVectorEnv
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.run_spec import build_run_spec

TRACK = stadium()  # 400 m straights, radius 80 m, 12 m wide


def _drive(obs: np.ndarray, target_mps: float) -> np.ndarray:
    """A line follower that corners too fast at a high target: it laps, then leaves the track."""
    angle = obs[K.OBS_ANGLE] * math.pi
    steer = np.clip(-2.0 * angle - 0.6 * obs[K.OBS_TRACKPOS], -1, 1)
    err = target_mps - obs[K.OBS_VX] * K.SPEED_SCALE_MPS
    return np.array([steer, np.clip(0.3 * err, 0, 1), np.clip(-0.2 * err, 0, 1)], np.float32)


@pytest.mark.parametrize("config", [{}, {"progress_reward": True, "track_pos_weight": 0.3}])
def test_the_parts_of_a_real_drive_sum_to_its_rewards(config: dict) -> None:
    """A lap and a crash on the stadium: every step's parts sum to its reward (1e-9); the
    paper's reward pays along and sideways, the progress reward pays progress instead; the
    off-track end pays -1 as its only part."""
    env = FormulaRacingEnv(config={"track": TRACK, "max_steps": 600} | config)
    obs, info = env.reset(options={"start_s_m": 300.0, "start_speed_mps": 20.0})
    assert dict(info["rewards"]) == dict.fromkeys(R.PARTS, 0.0)
    totals = dict.fromkeys(R.PARTS, 0.0)
    target, term, steps = 30.0, False, 0
    while not term:
        obs, r, term, trunc, info = env.step(_drive(obs, target))
        parts = dict(info["rewards"])
        assert list(parts) == list(R.PARTS)
        assert sum(parts.values()) == pytest.approx(r, abs=1e-9)
        for k, v in parts.items():
            totals[k] += v
        steps += 1
        if info["laps"] >= 1:
            target = 60.0  # too fast for the R80 turns: off the track
        assert not trunc and steps < 600
    assert info["termination"] == "off_track" and r == -1.0
    assert parts == dict.fromkeys(R.PARTS, 0.0) | {"end": -1.0}
    assert totals["track_pos"] < 0.0
    if config:
        assert totals["along"] == totals["sideways"] == 0.0 and totals["progress"] > 1000.0
    else:
        assert totals["progress"] == 0.0 and totals["along"] > 1000.0 > -totals["sideways"] > 0


def test_a_slow_end_pays_minus_slow_penalty_and_damage_is_its_own_part() -> None:
    env = FormulaRacingEnv(config={"track": TRACK, "slow_patience_steps": 3,
                                   "slow_penalty": 7.0})
    env.reset(options={"start_s_m": 100.0})
    for _ in range(3):
        _, r, term, _, info = env.step(np.zeros(3, np.float32))
    assert term and info["termination"] == "slow" and r == -7.0
    assert dict(info["rewards"]) == dict.fromkeys(R.PARTS, 0.0) | {"end": -7.0}
    # into the wall beside the straight (grass 5 m, then the wall), with no end to stop it
    env = FormulaRacingEnv(config={"track": TRACK, "terminate_off_track": False,
                                   "terminate_backwards": False, "terminate_slow": False})
    _, info = env.reset(options={"start_s_m": 100.0, "start_speed_mps": 25.0})
    damage, hits = info["damage"], 0
    for _ in range(25):
        _, r, term, _, info = env.step(np.array([1.0, 0.3, 0.0], np.float32))
        parts = info["rewards"]
        assert not term and sum(parts.values()) == pytest.approx(r, abs=1e-9)
        assert parts["damage"] == pytest.approx(-0.01 * (info["damage"] - damage), abs=1e-12)
        hits += info["damage"] > damage
        damage = info["damage"]
    assert hits >= 1  # a wall hit costs damage_weight x its damage


def _steer_off_the_straight(env: FormulaRacingEnv, speed_mps: float) -> tuple[float, float, dict]:
    """Full lock from 100 m down the stadium's straight at ``speed_mps`` until the car leaves the
    track: its Vx (m/s) at the step it left, that step's reward and info."""
    env.reset(options={"start_s_m": 100.0, "start_speed_mps": speed_mps})
    term, steps = False, 0
    while not term and steps < 100:
        obs, r, term, _, info = env.step(np.array([1.0, 0.0, 0.0], np.float32))
        steps += 1
    assert info["termination"] == "off_track"
    return float(obs[K.OBS_VX] * K.SPEED_SCALE_MPS), float(r), info


@pytest.mark.parametrize("weight", [0.0, 0.002])
def test_leaving_the_track_at_speed_pays_the_kinetic_energy_wall_penalty(weight: float) -> None:
    """Steered off the straight at 25 m/s and at 10 m/s: the off-track end pays -1 less
    wall_energy_weight x Vx^2 at the step it left (the faster start leaves at ~16 m/s: -1.5),
    the end part carries it, and at weight 0 it is the paper's -1 at any speed."""
    ends = {}
    for speed in (25.0, 10.0):
        env = FormulaRacingEnv(config={"track": TRACK, "wall_energy_weight": weight})
        vx, r, info = _steer_off_the_straight(env, speed)
        assert r == pytest.approx(-1.0 - weight * vx * vx, rel=1e-6)
        assert dict(info["rewards"]) == dict.fromkeys(R.PARTS, 0.0) | {"end": r}
        ends[speed] = r
    if weight:
        assert ends[25.0] < -1.4 and ends[25.0] < ends[10.0] < -1.0
    else:
        assert ends == {25.0: -1.0, 10.0: -1.0}


@pytest.mark.parametrize("limit_mps", [12.0, 20.0])
def test_leaving_the_track_above_the_limits_speed_pays_the_overspeed_penalty(
        limit_mps: float) -> None:
    """Steered off the straight from 25 m/s (it leaves at ~16 m/s): the off-track end pays -1
    less overspeed_crash_weight x (Vx^2 - v_limit^2) where the car's speed is above the limit's
    at that sample, and the paper's -1 where it is not; the end part carries it."""
    weight = 0.01
    speeds = (limit_mps,) * TRACK.n
    env = FormulaRacingEnv(config={"track": TRACK, "overspeed_crash_weight": weight,
                                   "limit_speeds_mps": speeds})
    assert env.unwrapped._b.geom[:, K.G_VLIM].tolist() == list(speeds)
    vx, r, info = _steer_off_the_straight(env, 25.0)
    assert 14.0 < vx < 18.0
    if limit_mps < vx:
        assert r == pytest.approx(-1.0 - weight * (vx * vx - limit_mps**2), rel=1e-6)
        assert r < -1.5
    else:
        assert r == -1.0
    assert dict(info["rewards"]) == dict.fromkeys(R.PARTS, 0.0) | {"end": r}


def test_the_overspeed_penalty_needs_one_limit_speed_per_track_sample() -> None:
    with pytest.raises(UserInputError, match="overspeed_crash_weight needs limit_speeds_mps"):
        FormulaRacingEnv(config={"track": TRACK, "overspeed_crash_weight": 0.1})
    with pytest.raises(UserInputError, match=f"3 values for track .* has {TRACK.n} samples"):
        FormulaRacingEnv(config={"track": TRACK, "overspeed_crash_weight": 0.1,
                                 "limit_speeds_mps": (20.0, 20.0, 20.0)})


def test_a_run_fills_the_limit_speeds_from_the_reference_limits_profile() -> None:
    """A run with the overspeed term gives its training and test envs the QSS speeds of the
    reference limit's lap, whose time is the reference limit (33.84 s on the oval); a run
    without it gives none. The oval's slowest point is far faster than technical's hairpins."""
    spec = build_run_spec(variant="WIN1", train_tracks=["oval"],
                          test_tracks=["oval", "technical"], preset="tuned",
                          env_overrides={"overspeed_crash_weight": 0.3})
    envs = RunEnvs(spec)
    car = spec.env.car_params()
    oval = envs.config("oval", test=False).limit_speeds_mps
    assert envs.config("oval", test=True).limit_speeds_mps == oval
    technical = envs.config("technical", test=True).limit_speeds_mps
    assert min(oval) > 55.0 and min(technical) < 25.0
    profile = speed_profile(envs.tracks["oval"],
                            reference_offsets(envs.tracks["oval"], "mincurv", car), car)
    assert np.array_equal(profile.speed_mps, oval)
    assert profile.lap_time_s == reference_limit_s(envs.tracks["oval"], car) == pytest.approx(
        33.84, abs=0.005)
    plain = RunEnvs(build_run_spec(variant="WIN1", train_tracks=["oval"], preset="tuned"))
    assert plain.config("oval", test=False).limit_speeds_mps == ()


def test_vector_parts_are_arrays_over_cars_and_sum_to_the_rewards() -> None:
    """Six cars with random actions, autoresets included: each car's parts sum to its reward
    (1e-9), and a car reset this step is paid nothing."""
    venv = FormulaRacingVectorEnv(num_envs=6, config={"track": TRACK, "random_start": True,
                                                       "start_speed_mps": 15.0})
    venv.reset(seed=2)
    rng = np.random.default_rng(4)
    ends = resets = 0
    needs_reset = np.zeros(6, bool)
    for _ in range(150):
        acts = rng.uniform([-0.4, 0, 0], [0.4, 1, 0.2], size=(6, 3)).astype(np.float32)
        _, rew, term, trunc, info = venv.step(acts)
        parts = info["rewards"]
        assert info["_rewards"].all() and set(parts) == set(R.PARTS)
        total = np.sum([parts[k] for k in R.PARTS], axis=0)
        np.testing.assert_allclose(total, rew, rtol=0, atol=1e-9)
        for k in R.PARTS:
            assert parts[k].shape == (6,)
            assert np.all(parts[k][needs_reset] == 0.0)
        resets += int(needs_reset.sum())
        ends += int(term.sum())
        needs_reset = term | trunc
    assert ends >= 3 and resets >= 3


def test_the_kernel_packing_comes_from_the_models_table() -> None:
    """Every weight the kernel reads sits at C_REWARD + its place in the table, every input at
    O_REWARD_IN + its place: a new setting or input takes the next slot, no index to write."""
    assert K.C_REWARD + len(R.KERNEL_NAMES) == K.N_CFG
    assert K.O_REWARD_IN + len(R.INPUT_NAMES) == K.N_OUT
    slots = {"track_pos_weight": K.C_TRACKPOS_W, "progress_reward": K.C_PROGRESS,
             "damage_weight": K.C_DMG_W, "slow_penalty": K.C_SLOW_PEN,
             "early_end_reward": K.C_END_REWARD, "wall_energy_weight": K.C_WALL_E,
             "overspeed_crash_weight": K.C_OVERSPEED}
    assert sorted(slots) == sorted(R.KERNEL_NAMES)
    assert sorted(slots.values()) == list(range(K.C_REWARD, K.N_CFG))
    others = [v for k, v in vars(K).items() if k.startswith("C_") and k != "C_REWARD"
              and v not in slots.values()]
    assert sorted(others) == list(range(K.C_REWARD))  # the env's own settings come first
    outs = [K.O_REWARD, K.O_TERM, K.O_DMG_INC, K.O_VX, K.O_ANGLE, K.O_TRACKPOS, K.O_PROGRESS]
    assert outs == list(range(K.O_REWARD_IN, K.N_OUT))
    env = FormulaRacingEnv(config={"track": TRACK, "track_pos_weight": 0.4, "slow_penalty": 3.0,
                                   "progress_reward": True, "damage_weight": 0.5})
    block = env._b.cfg[K.C_REWARD:]
    assert dict(zip(R.KERNEL_NAMES, block.tolist(), strict=True)) == {
        "track_pos_weight": 0.4, "progress_reward": 1.0, "damage_weight": 0.5,
        "slow_penalty": 3.0, "early_end_reward": -1.0, "wall_energy_weight": 0.0,
        "overspeed_crash_weight": 0.0}


def test_each_setting_is_declared_once_in_the_table() -> None:
    """The env's and the agent's reward keys are the table's Fields: same default, bounds,
    description and marks (added within layout 2, beyond the paper)."""
    for s in R.SETTINGS:
        if s.home == "fixed":
            assert s.name not in EnvSettings.model_fields
            assert s.name not in AgentConfig.model_fields
            continue
        model = EnvSettings if s.home == "env" else AgentConfig
        field = model.model_fields[s.name]
        assert field.default == s.default and field.description == s.description
        assert added_in_layout(field) == s.added_in_layout
        assert beyond_paper(field) == s.beyond_paper
    assert [s.name for s in R.SETTINGS if s.beyond_paper] == [
        "track_pos_weight", "progress_reward", "wall_energy_weight", "overspeed_crash_weight",
        "crash_penalty", "crash_penalty_decay_steps"]
    with pytest.raises(ValueError, match="less than or equal to 10"):
        EnvSettings(track_pos_weight=11.0)
    with pytest.raises(ValueError, match="greater than 0"):
        AgentConfig(reward_scale=0.0)


def test_the_reward_settings_keep_the_config_hash_of_existing_runs() -> None:
    """Config hashes of runs (the paper's, a crash penalty, the progress reward) as written
    before the reward model, so that a resumed tournament still finds their jobs finished. The
    paper's is the hash of the layout before. ``best`` took the overspeed crash penalty and
    later the classification critic with the steer's saturation term: each gave its runs a new
    hash, and the former ``best`` (those set back to the paper's) keeps the old. ``best-demos``
    became ``best`` with demonstrations: its former settings (``tuned-bc`` with a crash penalty)
    keep their hash under the preset they are now written with."""
    digests = {preset: build_run_spec(variant="WIN1", train_tracks=["oval"],
                                      preset=preset).digest()
               for preset in ("paper", "best-demos", "best")}  # fmt: skip
    assert digests == {"paper": "b96be71af1f8944f", "best-demos": "8a067c02fa04c086",
                       "best": "fb1b6d477ce47dbb"}
    paper_critic = {"critic_bins": 0, "preact_penalty": 0.0, "preact_bound": (6.0, 6.0)}
    former = build_run_spec(variant="WIN1", train_tracks=["oval"], preset="best",
                            overrides=paper_critic)
    assert former.digest() == "e41b92054560af51"
    former = build_run_spec(variant="WIN1", train_tracks=["oval"], preset="best",
                            overrides=paper_critic,
                            env_overrides={"overspeed_crash_weight": 0.0})
    assert former.digest() == "b7cb11ff96e7fa13"
    crash = build_run_spec(variant="WIN1", train_tracks=["oval"], preset="tuned-bc",
                           overrides={"actor_lr": 1e-4, "crash_penalty": 1000.0,
                                      "eval_ema_updates": 3000})  # fmt: skip
    assert crash.digest() == "677b5ec443979c9d"
    assert R.RewardRule.of(crash.agent) == R.RewardRule(scale=0.02, crash_penalty=1000.0)


def test_cached_kernels_are_forgotten_when_the_tables_they_read_change(tmp_path) -> None:
    """numba freezes the derived indices into its cache: a changed table layout flushes the
    cached kernels once (and writes its digest), an unchanged one leaves them."""

    class Cache:
        cache_path = str(tmp_path)
        flushes = 0

        def flush(self) -> None:
            Cache.flushes += 1

    class Kernel:
        _cache = Cache()

    K.drop_stale_cache([Kernel, Kernel], b"layout 1", "marker")
    assert Cache.flushes == 2 and (tmp_path / "marker").exists()
    K.drop_stale_cache([Kernel, Kernel], b"layout 1", "marker")
    assert Cache.flushes == 2
    K.drop_stale_cache([Kernel, Kernel], b"layout 2", "marker")
    assert Cache.flushes == 4
