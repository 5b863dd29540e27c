"""Compiled race step: N cars advanced in lockstep, substep by substep, with car-car contact.

The plain vector env (:func:`kernels.step_cars`) runs each car's 20 physics substeps in one go,
because its cars pass through each other. Cars that touch must be advanced together: a car at
80 m/s moves 16 m in a 0.2 s control step, far more than a car length, so contact tested once a
step would miss most collisions. Here every substep first advances each driving car through
:func:`kernels.track_substep` (the per-car dynamics, projection, walls and lap timing of the
single-car path, unchanged) and then resolves contacts between the cars. Without contact every
car runs exactly the arithmetic of :func:`kernels.step_cars` (tests/test_race_sim.py compares
the two bit for bit).

Contact (:func:`resolve_pair`): each car is its body rectangle (``car_length_m`` x
``car_width_m``), an oriented box; two boxes overlap when all four separating axes (the boxes'
own axes) overlap (2-D SAT, exact for rectangles). The axis of least overlap gives the normal,
the incident box's deepest corner (the middle of its two deepest corners when an edge lies flat
on the other box, as when two cars touch side by side) the contact point. The impulse is the
rigid-body one with restitution and Coulomb friction, applied equal and opposite to the two
cars, so linear and angular momentum are conserved to rounding. The kinetic energy the impulse
takes out of the pair is the impact energy; each car takes ``damage_per_kj`` per kJ of its half.

Opponent sensors (:func:`opponent_sensors`): SCR's 36 sectors of 10 deg around the car, each
the distance to the nearest other car (centre to centre) within 200 m, normalised by 200 (1.0 when
the sector is empty).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numba import njit

from formula_tourney.sim import kernels as K

# --- per-car scratch columns (one control step's held controls) ---------------------------------
SC_STEER = 0
SC_THROTTLE = 1
SC_BRAKE = 2
SC_CD = 3  # cos and sin of the front wheel angle
SC_SD = 4
SC_CP = 5  # carried cos and sin of the yaw (see kernels.physics_substep)
SC_SP = 6
SC_DMG0 = 7  # damage and progress at the start of the step
SC_DIST0 = 8
N_SCRATCH = 9

# --- contact parameters -------------------------------------------------------------------------
CT_ON = 0  # 1: cars collide; 0: they pass through each other (the vector env's behaviour)
CT_RESTITUTION = 1
CT_FRICTION = 2
CT_DAMAGE_PER_J = 3
N_CONTACT = 4

# --- car modes ----------------------------------------------------------------------------------
MODE_PLACED = 0  # just placed: located and observed, not integrated (reward 0, no flags)
MODE_DRIVING = 1
MODE_OUT = 2  # finished or retired: left the track (not integrated, not touched, not seen)

N_OPP = 36
OPP_SECTOR_RAD = math.pi / 18.0
OPP_RANGE_M = 200.0
NEAR_MARGIN_M = 1.0
NEAR_ACCEL_MPS2 = 40.0
_DEEP_TIE_M = 1e-3
"""Corners of the incident box within this depth of the deepest share the contact point."""


@njit(cache=True, _nrt=False)
def resolve_pair(sa: np.ndarray, sb: np.ndarray, p: np.ndarray, ct: np.ndarray):
    """Resolve the contact between cars ``sa`` and ``sb`` (state rows) in place.

    Returns ``(touching, energy_j, share_a)``: whether the boxes overlap, the kinetic energy the
    impulse removed (J) and the share of the closing speed that car ``a`` brought (the car that
    drove into the other "caused" the contact; 0.5 when neither closed).
    """
    hl = 0.5 * p[K.P_LEN]
    hw = 0.5 * p[K.P_WID]
    dx = sb[K.ST_X] - sa[K.ST_X]
    dy = sb[K.ST_Y] - sa[K.ST_Y]
    reach = 2.0 * p[K.P_REACH]
    if dx * dx + dy * dy >= reach * reach:
        return False, 0.0, 0.5
    ca = math.cos(sa[K.ST_PSI])
    sna = math.sin(sa[K.ST_PSI])
    cb = math.cos(sb[K.ST_PSI])
    snb = math.sin(sb[K.ST_PSI])
    # Separating axes: a's x and y, b's x and y.
    best = 1e300
    nx = 0.0
    ny = 0.0
    ref_a = True
    for k in range(4):
        if k == 0:
            ax, ay = ca, sna
        elif k == 1:
            ax, ay = -sna, ca
        elif k == 2:
            ax, ay = cb, snb
        else:
            ax, ay = -snb, cb
        ra = hl * abs(ca * ax + sna * ay) + hw * abs(-sna * ax + ca * ay)
        rb = hl * abs(cb * ax + snb * ay) + hw * abs(-snb * ax + cb * ay)
        d = dx * ax + dy * ay
        overlap = ra + rb - abs(d)
        if overlap <= 0.0:
            return False, 0.0, 0.5
        if overlap < best:
            best = overlap
            sgn = 1.0 if d >= 0.0 else -1.0
            nx = sgn * ax  # from a towards b
            ny = sgn * ay
            ref_a = k < 2
    # Contact point: the incident box's deepest corner(s) along the normal.
    if ref_a:  # b's corners, deepest = smallest projection on n
        ox, oy, c, s, sign = sb[K.ST_X], sb[K.ST_Y], cb, snb, -1.0
    else:  # a's corners, deepest = largest projection on n
        ox, oy, c, s, sign = sa[K.ST_X], sa[K.ST_Y], ca, sna, 1.0
    deepest = -1e300
    for k in range(4):
        lx = hl if k < 2 else -hl
        ly = hw if k % 2 == 0 else -hw
        depth = sign * ((c * lx - s * ly) * nx + (s * lx + c * ly) * ny)
        if depth > deepest:
            deepest = depth
    px = 0.0
    py = 0.0
    cnt = 0.0
    for k in range(4):
        lx = hl if k < 2 else -hl
        ly = hw if k % 2 == 0 else -hw
        wx = c * lx - s * ly
        wy = s * lx + c * ly
        if sign * (wx * nx + wy * ny) >= deepest - _DEEP_TIE_M:
            px += ox + wx
            py += oy + wy
            cnt += 1.0
    px /= cnt
    py /= cnt
    # Separate the boxes along the normal (equal cars: half each; momentum is untouched).
    half = 0.5 * best
    sa[K.ST_X] -= half * nx
    sa[K.ST_Y] -= half * ny
    sb[K.ST_X] += half * nx
    sb[K.ST_Y] += half * ny
    m = p[K.P_MASS]
    iz = p[K.P_IZ]
    inv_m = 1.0 / m
    inv_iz = 1.0 / iz
    # World velocities and lever arms.
    vax = sa[K.ST_VX] * ca - sa[K.ST_VY] * sna
    vay = sa[K.ST_VX] * sna + sa[K.ST_VY] * ca
    vbx = sb[K.ST_VX] * cb - sb[K.ST_VY] * snb
    vby = sb[K.ST_VX] * snb + sb[K.ST_VY] * cb
    wa = sa[K.ST_R]
    wb = sb[K.ST_R]
    rax = px - sa[K.ST_X]
    ray = py - sa[K.ST_Y]
    rbx = px - sb[K.ST_X]
    rby = py - sb[K.ST_Y]
    # Contact-point velocities (v + w x r) and the closing speed along n.
    pax = vax - wa * ray
    pay = vay + wa * rax
    pbx = vbx - wb * rby
    pby = vby + wb * rbx
    app_a = pax * nx + pay * ny  # a moving towards b
    app_b = -(pbx * nx + pby * ny)  # b moving towards a
    pos_a = max(app_a, 0.0)
    pos_b = max(app_b, 0.0)
    share_a = pos_a / (pos_a + pos_b) if pos_a + pos_b > 1e-12 else 0.5
    vn = (pbx - pax) * nx + (pby - pay) * ny
    if vn >= 0.0:
        return True, 0.0, share_a
    e0 = (0.5 * m * (vax * vax + vay * vay + vbx * vbx + vby * vby)
          + 0.5 * iz * (wa * wa + wb * wb))
    rna = rax * ny - ray * nx
    rnb = rbx * ny - rby * nx
    jn = -(1.0 + ct[CT_RESTITUTION]) * vn / (2.0 * inv_m + (rna * rna + rnb * rnb) * inv_iz)
    vax -= jn * nx * inv_m
    vay -= jn * ny * inv_m
    wa -= jn * rna * inv_iz
    vbx += jn * nx * inv_m
    vby += jn * ny * inv_m
    wb += jn * rnb * inv_iz
    # Coulomb friction along the contact, at most enough to stop the sliding.
    pax = vax - wa * ray
    pay = vay + wa * rax
    pbx = vbx - wb * rby
    pby = vby + wb * rbx
    rvx = pbx - pax
    rvy = pby - pay
    vn2 = rvx * nx + rvy * ny
    tx = rvx - vn2 * nx
    ty = rvy - vn2 * ny
    vt = math.sqrt(tx * tx + ty * ty)
    if vt > 1e-9:
        tx /= vt
        ty /= vt
        rta = rax * ty - ray * tx
        rtb = rbx * ty - rby * tx
        jt = min(ct[CT_FRICTION] * jn, vt / (2.0 * inv_m + (rta * rta + rtb * rtb) * inv_iz))
        # b slides along +t relative to a: friction pushes b back and a forward.
        vax += jt * tx * inv_m
        vay += jt * ty * inv_m
        wa += jt * rta * inv_iz
        vbx -= jt * tx * inv_m
        vby -= jt * ty * inv_m
        wb -= jt * rtb * inv_iz
    e1 = (0.5 * m * (vax * vax + vay * vay + vbx * vbx + vby * vby)
          + 0.5 * iz * (wa * wa + wb * wb))
    sa[K.ST_VX] = vax * ca + vay * sna
    sa[K.ST_VY] = -vax * sna + vay * ca
    sa[K.ST_R] = wa
    sb[K.ST_VX] = vbx * cb + vby * snb
    sb[K.ST_VY] = -vbx * snb + vby * cb
    sb[K.ST_R] = wb
    return True, max(e0 - e1, 0.0), share_a


@njit(cache=True, _nrt=False)
def resolve_contacts(state: np.ndarray, mode: np.ndarray, near: np.ndarray, p: np.ndarray,
                     ct: np.ndarray, pair_touch: np.ndarray, pair_energy: np.ndarray,
                     pair_blame: np.ndarray) -> None:
    """Every pair of driving cars flagged ``near`` once (the bounding-circle test rejects most).

    Accumulates per pair: ``pair_touch[a, b]`` (a < b) set when the boxes overlapped,
    ``pair_energy[a, b]`` the impact energy (J) and ``pair_blame[a, b]`` the energy that car
    ``a`` caused in its contacts with ``b`` (``pair_blame[b, a]`` the rest). Damage goes on the
    cars' ``ST_DAMAGE``.
    """
    n = state.shape[0]
    dmg = ct[CT_DAMAGE_PER_J]
    for a in range(n):
        if mode[a] != MODE_DRIVING or near[a] == 0:
            continue
        for b in range(a + 1, n):
            if mode[b] != MODE_DRIVING or near[b] == 0:
                continue
            touching, energy, share_a = resolve_pair(state[a], state[b], p, ct)
            if touching:
                pair_touch[a, b] = 1.0
                pair_energy[a, b] += energy
                pair_blame[a, b] += energy * share_a
                pair_blame[b, a] += energy * (1.0 - share_a)
                state[a, K.ST_DAMAGE] += 0.5 * dmg * energy
                state[b, K.ST_DAMAGE] += 0.5 * dmg * energy


@njit(cache=True, _nrt=False)
def opponent_sensors(state: np.ndarray, mode: np.ndarray, opp: np.ndarray) -> None:
    """SCR opponent sensors of every car that is on the track.

    Sector ``k`` holds the cars whose bearing from this car's heading (left > 0, as the range
    finders) is in ``[-180 + 10 k, -170 + 10 k)`` deg: straight ahead (0 deg) opens sector 18.
    Value: distance between the centres / 200 m, 1.0 (200 m) when no car is nearer.
    """
    n = state.shape[0]
    for c in range(n):
        row = opp[c]
        for k in range(N_OPP):
            row[k] = 1.0
        if mode[c] == MODE_OUT:
            continue
        x = state[c, K.ST_X]
        y = state[c, K.ST_Y]
        psi = state[c, K.ST_PSI]
        for d in range(n):
            if d == c or mode[d] == MODE_OUT:
                continue
            dx = state[d, K.ST_X] - x
            dy = state[d, K.ST_Y] - y
            dist = math.sqrt(dx * dx + dy * dy)
            if dist >= OPP_RANGE_M:
                continue
            bearing = math.atan2(dy, dx) - psi
            bearing = (bearing + math.pi) % (2.0 * math.pi)  # [0, 2 pi): -180 deg at 0
            k = int(bearing / OPP_SECTOR_RAD)
            if k >= N_OPP:
                k = N_OPP - 1
            v = dist / OPP_RANGE_M
            if v < row[k]:
                row[k] = v


@njit(cache=True, _nrt=False)
def mark_near(state: np.ndarray, mode: np.ndarray, p: np.ndarray, period_s: float,
              near: np.ndarray) -> None:
    """Flag the driving cars that could touch another within the next control period.

    Two cars can close at most ``(|v_a| + |v_b|) T + a_max T^2`` in a period ``T`` (``a_max``
    generous: 4 g each); cars farther apart than that plus both bodies' reach cannot meet, and
    drive the single-car path (``kernels.control_step``, the vector env's own arithmetic).
    """
    n = state.shape[0]
    for c in range(n):
        near[c] = 0
    reach = 2.0 * p[K.P_REACH] + NEAR_MARGIN_M
    for a in range(n):
        if mode[a] != MODE_DRIVING:
            continue
        va = math.hypot(state[a, K.ST_VX], state[a, K.ST_VY])
        for b in range(a + 1, n):
            if mode[b] != MODE_DRIVING:
                continue
            vb = math.hypot(state[b, K.ST_VX], state[b, K.ST_VY])
            lim = reach + (va + vb) * period_s + 2.0 * NEAR_ACCEL_MPS2 * period_s * period_s
            dx = state[b, K.ST_X] - state[a, K.ST_X]
            dy = state[b, K.ST_Y] - state[a, K.ST_Y]
            if dx * dx + dy * dy < lim * lim:
                near[a] = 1
                near[b] = 1


@njit(cache=True, fastmath=K._FAST, _nrt=False)
def step_race(state: np.ndarray, actions: np.ndarray, mode: np.ndarray, p: np.ndarray,
              torque: np.ndarray, gears: np.ndarray, geoms: np.ndarray, ref_of_car: np.ndarray,
              elev: np.ndarray, cfgs: np.ndarray, lac_d: np.ndarray, obs: np.ndarray,
              out: np.ndarray, scratch: np.ndarray, near: np.ndarray, ct: np.ndarray,
              pair_touch: np.ndarray, pair_energy: np.ndarray, pair_blame: np.ndarray,
              opp: np.ndarray, with_opponents: bool) -> None:
    """One control step of a race: N cars, contact after each substep where cars are close.

    ``geoms[ref_of_car[c]]`` is car ``c``'s geometry block: every layer has the same track
    columns (so the physics is the same) and its own reference line (what the car's telemetry
    and reward are measured against: each entrant sees the line it was trained on).
    ``cfgs[c]`` is its configuration row (LAC, ends, reward weights; control period and
    substeps equal for all). The pair arrays are cleared, then filled for this step.

    Cars that cannot meet another this period (:func:`mark_near`; all of them when contact is
    off) take the single-car path, :func:`kernels.control_step`, so they drive bit-identically
    to the vector env. The others advance in lockstep through :func:`kernels.track_substep`
    (the same per-car arithmetic; the compiled loop differs, so results can differ from the
    single-car path in the last bit) with :func:`resolve_contacts` after every substep.
    """
    n = state.shape[0]
    for a in range(n):
        for b in range(n):
            pair_touch[a, b] = 0.0
            pair_energy[a, b] = 0.0
            pair_blame[a, b] = 0.0
    n_sub = int(cfgs[0, K.C_NSUB])
    dt = cfgs[0, K.C_DT] / n_sub
    collide = ct[CT_ON] > 0.5
    if collide:
        mark_near(state, mode, p, cfgs[0, K.C_DT], near)
    else:
        for c in range(n):
            near[c] = 0
    lockstep = False
    for c in range(n):
        st = state[c]
        o = out[c]
        geom = geoms[ref_of_car[c]]
        cfg = cfgs[c]
        if mode[c] == MODE_OUT:
            o[K.O_REWARD] = 0.0
            o[K.O_TERM] = K.TERM_NONE
            o[K.O_TRUNC] = 0.0
            o[K.O_LAP_TIME] = np.nan
            o[K.O_DMG_INC] = 0.0
        elif mode[c] == MODE_PLACED:
            K._locate(st, geom, cfg[K.C_LENGTH])
            K.observe(st, geom, elev, cfg, lac_d, obs[c])
            o[K.O_REWARD] = 0.0
            o[K.O_TERM] = K.TERM_NONE
            o[K.O_TRUNC] = 0.0
            o[K.O_LAP_TIME] = np.nan
            o[K.O_DMG_INC] = 0.0
        elif near[c] == 0:  # the body of kernels._step_one
            dist0 = st[K.ST_DIST]
            K.control_step(st, actions[c], p, torque, gears, geom, elev, cfg, o)
            angle = K.observe(st, geom, elev, cfg, lac_d, obs[c])
            K.score_step(st, o, obs[c], dist0, angle, geom, cfg)
        else:
            lockstep = True
            # The prologue of kernels.control_step (clipped controls, NaN -> coast).
            act = actions[c]
            steer = K._clip(act[0], -1.0, 1.0)
            throttle = K._clip(act[1], 0.0, 1.0)
            brake = K._clip(act[2], 0.0, 1.0)
            if math.isnan(steer) or math.isnan(throttle) or math.isnan(brake):
                steer, throttle, brake = 0.0, 0.0, 0.0
            sc = scratch[c]
            sc[SC_STEER] = steer
            sc[SC_THROTTLE] = throttle
            sc[SC_BRAKE] = brake
            sc[SC_CD] = math.cos(steer * p[K.P_STEER])
            sc[SC_SD] = math.sin(steer * p[K.P_STEER])
            sc[SC_CP] = math.cos(st[K.ST_PSI])
            sc[SC_SP] = math.sin(st[K.ST_PSI])
            sc[SC_DMG0] = st[K.ST_DAMAGE]
            sc[SC_DIST0] = st[K.ST_DIST]
            o[K.O_LAP_TIME] = np.nan
    if lockstep:
        for _ in range(n_sub):
            for c in range(n):
                if mode[c] != MODE_DRIVING or near[c] == 0:
                    continue
                sc = scratch[c]
                geom = geoms[ref_of_car[c]]
                cfg = cfgs[c]
                length = cfg[K.C_LENGTH]
                if cfg[K.C_ELEV] > 0.5:
                    cp, sp = K.track_substep(state[c], sc[SC_STEER], sc[SC_CD], sc[SC_SD],
                                             sc[SC_THROTTLE], sc[SC_BRAKE], p, torque, gears,
                                             geom, elev, cfg, out[c], length, dt, sc[SC_CP],
                                             sc[SC_SP], True)
                else:
                    cp, sp = K.track_substep(state[c], sc[SC_STEER], sc[SC_CD], sc[SC_SD],
                                             sc[SC_THROTTLE], sc[SC_BRAKE], p, torque, gears,
                                             geom, elev, cfg, out[c], length, dt, sc[SC_CP],
                                             sc[SC_SP], False)
                sc[SC_CP] = cp
                sc[SC_SP] = sp
            resolve_contacts(state, mode, near, p, ct, pair_touch, pair_energy, pair_blame)
        for c in range(n):
            if mode[c] != MODE_DRIVING or near[c] == 0:
                continue
            st = state[c]
            geom = geoms[ref_of_car[c]]
            cfg = cfgs[c]
            o = out[c]
            st[K.ST_STEPS] += 1.0
            o[K.O_DMG_INC] = st[K.ST_DAMAGE] - scratch[c, SC_DMG0]
            angle = K.observe(st, geom, elev, cfg, lac_d, obs[c])
            K.score_step(st, o, obs[c], scratch[c, SC_DIST0], angle, geom, cfg)
    if with_opponents:
        opponent_sensors(state, mode, opp)


_CACHED = (resolve_pair, resolve_contacts, opponent_sensors, mark_near, step_race)

# These kernels compile the functions of ``kernels.py`` into themselves (measured once, before
# this check: a changed ``kernels.py`` left the race step 1 ulp off the vector env).
K.drop_stale_cache(_CACHED, Path(K.__file__).read_bytes() + K.REWARD_LAYOUT,
                   "lockstep_kernels.kernels-sha1")
