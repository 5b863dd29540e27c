"""Cars that interact: the race kernel against the vector env, contacts, opponent sensors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from simtracks import stadium

from formula_tourney.errors import UserInputError
from formula_tourney.sim import kernels as K
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.env import FormulaRacingEnv, FormulaRacingVectorEnv
from formula_tourney.sim.multicar import lockstep_kernels as RK
from formula_tourney.sim.multicar.simulator import OPPONENT_NAMES, ContactSettings, RaceSim

TRACK = stadium()
FREE = {"track": TRACK, "random_start": True, "terminate_off_track": False,
        "terminate_backwards": False, "terminate_slow": False, "max_steps": 10_000}


def _fresh_compile() -> bool:
    """Whether either kernel was compiled in this process rather than loaded from numba's
    cache: a kernel compiled fresh can differ in the last bit from the same kernel loaded
    from the cache (docs/sim.md, "Speed"), so bit-identity is asserted between cached ones."""
    return bool(K.step_cars.stats.cache_misses or RK.step_race.stats.cache_misses)


def _equal(actual: np.ndarray, desired: np.ndarray) -> None:
    if _fresh_compile():
        np.testing.assert_allclose(actual, desired, rtol=1e-9, atol=1e-9)
    else:
        np.testing.assert_array_equal(actual, desired)


def _compare_with_vector(n: int, contact: bool, seed: int, steps: int, lac: bool) -> RaceSim:
    cfg = {**FREE, "lac": lac}
    venv = FormulaRacingVectorEnv(num_envs=n, config=cfg)
    venv.reset(seed=seed)
    sim = RaceSim([cfg] * n, ContactSettings(enabled=contact), opponents=True)
    sim.state[:] = venv._b.state
    sim.mode[:] = RK.MODE_DRIVING
    rng = np.random.default_rng(seed)
    bias = 0.4 * (-1.0) ** np.arange(n)  # cars pulling left and right find the walls
    for _ in range(steps):
        a = rng.uniform([-1, 0, 0], [1, 1, 1], size=(n, 3))
        a[:, 0] = np.clip(a[:, 0] + bias, -1, 1)
        obs, rew, term, trunc, _ = venv.step(a)
        sim.step(a)
        assert not sim.pair_touch.any()
        assert not (term.any() or trunc.any())
        _equal(sim.obs[:, :obs.shape[1]], obs)
        _equal(sim.out[:, K.O_REWARD], rew)
        _equal(sim.state, venv._b.state)
    return sim


def test_n_cars_without_contact_match_the_vector_env_bit_for_bit():
    sim = _compare_with_vector(n=6, contact=False, seed=3, steps=300, lac=True)
    assert sim.state[:, K.ST_DAMAGE].max() > 0.0  # random driving hit the walls: walls tested


def test_cars_apart_with_contact_on_match_the_vector_env():
    _compare_with_vector(n=3, contact=True, seed=11, steps=150, lac=False)


def test_solo_race_car_matches_the_single_env():
    cfg = {**FREE, "random_start": False, "start_speed_mps": 20.0}
    env = FormulaRacingEnv(config=cfg)
    env.reset(seed=0, options={"start_s_m": 150.0})
    sim = RaceSim([cfg], opponents=True)
    sim.state[0] = env._b.state[0]
    sim.mode[0] = RK.MODE_DRIVING
    rng = np.random.default_rng(2)
    for _ in range(100):
        a = rng.uniform([-0.3, 0, 0], [0.3, 1, 0.2])
        obs, rew, *_ = env.step(a.astype(np.float32))
        sim.step(a[None].astype(np.float32).astype(np.float64))
        _equal(sim.observation(0), obs)
        _equal(sim.out[0, K.O_REWARD], rew)
    assert (sim.opp == 1.0).all()  # alone: every sector empty


def _world(st: np.ndarray) -> tuple[float, float]:
    c, s = math.cos(st[K.ST_PSI]), math.sin(st[K.ST_PSI])
    return st[K.ST_VX] * c - st[K.ST_VY] * s, st[K.ST_VX] * s + st[K.ST_VY] * c


def _momenta(sa: np.ndarray, sb: np.ndarray, m: float, iz: float) -> tuple[float, float, float]:
    """Linear momentum (x, y) and angular momentum about the origin of the pair."""
    px = py = lz = 0.0
    for st in (sa, sb):
        vx, vy = _world(st)
        px += m * vx
        py += m * vy
        lz += m * (st[K.ST_X] * vy - st[K.ST_Y] * vx) + iz * st[K.ST_R]
    return px, py, lz


def test_side_by_side_contact_conserves_momentum():
    car = CarParams()
    sim = RaceSim([{"track": TRACK}] * 2)
    gap = car.car_width_m - 0.04  # 4 cm overlap
    sim.place(0, 100.0, -gap / 2, 40.0)
    sim.place(1, 100.0, gap / 2, 40.0)
    sa, sb = sim.state[0], sim.state[1]
    sa[K.ST_VY] = 3.0  # car 0 (right) drifts left into car 1 at 3 m/s
    m, iz = car.mass_kg, sim.params[K.P_IZ]
    before = _momenta(sa, sb, m, iz)
    touching, energy, share_a = RK.resolve_pair(sa, sb, sim.params, sim.ct)
    after = _momenta(sa, sb, m, iz)
    assert touching and share_a == pytest.approx(1.0)  # car 0 drove into car 1
    assert after[0] == pytest.approx(before[0], rel=1e-12)
    assert after[1] == pytest.approx(before[1], abs=1e-9 * abs(before[0]))
    assert after[2] == pytest.approx(before[2], rel=1e-10)
    # Restitution 0.2: the 3 m/s closing speed becomes 0.6 m/s apart; side by side the contact
    # point is between the centres, so no spin.
    va, vb = _world(sa), _world(sb)
    assert vb[1] - va[1] == pytest.approx(0.6, rel=1e-9)
    assert sa[K.ST_R] == pytest.approx(0.0, abs=1e-12) and sb[K.ST_R] == pytest.approx(0.0,
                                                                                      abs=1e-12)
    # Energy removed: 1/2 mu (1 - e^2) vn^2 with the reduced mass m/2.
    assert energy == pytest.approx(0.5 * (m / 2) * (1 - 0.2 ** 2) * 3.0 ** 2, rel=1e-9)
    assert sb[K.ST_Y] - sa[K.ST_Y] == pytest.approx(car.car_width_m, rel=1e-9)  # separated


def test_oblique_contact_conserves_momentum_and_spins_the_cars():
    car = CarParams()
    sim = RaceSim([{"track": TRACK}] * 2)
    sim.place(0, 100.0, 0.0, 45.0)
    sim.place(1, 104.0, 1.2, 30.0, heading_offset_rad=0.4)  # rear-ended at an angle
    sa, sb = sim.state[0], sim.state[1]
    sb[K.ST_R] = 0.3
    m, iz = car.mass_kg, sim.params[K.P_IZ]
    va0, vb0 = sa.copy(), sb.copy()
    touching, energy, share_a = RK.resolve_pair(sa, sb, sim.params, sim.ct)
    assert touching and energy > 0.0 and share_a > 0.5  # the faster car behind ran in
    assert sa[K.ST_R] != 0.0 and sb[K.ST_R] != 0.3  # an off-centre hit spins both
    # The boxes are first pushed apart (a projection: no velocity changes), then the impulse
    # acts: compare the momenta at the separated positions with the velocities before and after.
    for row, old in ((va0, sa), (vb0, sb)):
        row[[K.ST_X, K.ST_Y]] = old[[K.ST_X, K.ST_Y]]
    before = _momenta(va0, vb0, m, iz)
    after = _momenta(sa, sb, m, iz)
    assert after[0] == pytest.approx(before[0], rel=1e-12)
    assert after[1] == pytest.approx(before[1], abs=1e-12 * m * 45.0)
    assert after[2] == pytest.approx(before[2], rel=1e-11)


def test_contact_in_the_race_step_damages_both_and_is_blamed_on_the_driver_who_turned_in():
    car = CarParams()
    sim = RaceSim([{"track": TRACK}] * 2, ContactSettings(damage_per_kj=50.0))
    sim.place(0, 60.0, -1.2, 30.0)
    sim.place(1, 60.0, 1.2, 30.0)
    sim.step()
    touched = energy = 0.0
    blame = np.zeros(2)
    for _ in range(5):
        sim.step(np.array([[0.6, 0.5, 0.0], [0.0, 0.5, 0.0]]))  # car 0 steers left into car 1
        touched += sim.pair_touch[0, 1]
        energy += sim.pair_energy[0, 1]
        blame += [sim.pair_blame[0, 1], sim.pair_blame[1, 0]]
    assert touched >= 1 and energy > 0.0
    assert blame[0] > blame[1]
    d = sim.state[:, K.ST_DAMAGE]
    assert d[0] > 0 and d[1] > 0 and d.sum() == pytest.approx(0.05 * energy, rel=1e-9)
    gap = np.hypot(*(sim.state[1, :2] - sim.state[0, :2]))
    assert gap > car.car_width_m - 0.05  # not driven through each other


def test_opponent_sensors_see_a_car_30_m_ahead_in_the_front_sector():
    sim = RaceSim([{"track": TRACK}] * 4)
    sim.place(0, 100.0)
    sim.place(1, 130.0)  # 30 m ahead on the straight, dead ahead
    sim.place(2, 100.0, 5.0)  # 5 m to the left: bearing +90 deg
    sim.place(3, 330.0)  # 230 m ahead: out of range
    sim.step()
    opp = sim.opp[0]
    front = OPPONENT_NAMES.index("opp_0")
    assert front == 18
    assert opp[front] == pytest.approx(30.0 / 200.0, abs=1e-12)
    left = OPPONENT_NAMES.index("opp_90")
    assert opp[left] == pytest.approx(5.0 / 200.0, abs=1e-12)
    others = np.delete(opp, [front, left])
    assert (others == 1.0).all()
    # Car 1 sees car 0 behind it (bearing 180 deg = -180: the first sector) at 30 m.
    assert sim.opp[1, 0] == pytest.approx(30.0 / 200.0, abs=1e-12)
    # A car that left the track is not seen.
    sim.remove(1)
    sim.step(np.zeros((4, 3)))
    assert sim.opp[0, front] == 1.0
    assert sim.observation(0, with_opponents=True).shape == (29 + 36,)


def test_cars_that_disagree_on_shared_settings_are_refused():
    with pytest.raises(UserInputError, match="car 2: its car differs"):
        RaceSim([{"track": TRACK}, {"track": TRACK, "car": {"mass_kg": 1200.0}}])
    with pytest.raises(UserInputError, match="race actions"):
        RaceSim([{"track": TRACK}]).step(np.zeros((2, 3)))
    with pytest.raises(UserInputError, match="at least one car"):
        RaceSim([])
