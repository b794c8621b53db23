"""The paper's discrete EAV model, as a pure transition function.

Paper (z up, thrust along body +z):
    X_k = 2 X_{k-1} - X_{k-2} + dt²/m ( R_k T_k e3 - m g e3 - (k_d/dt)(X_{k-1} - X_{k-2}) + xi_k )
Here in NED/FRD (z down, thrust along body -z), the same equation reads
    X_k = 2 X_{k-1} - X_{k-2} + dt²/m ( -R_k T_k e3 + m g e3 - (k_d/dt)(X_{k-1} - X_{k-2}) + xi_k )
No I/O, no clock: the caller passes the state, the command, the parameters and the random generator.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from viva_sitl.dynamics.params import EavParams, WindParams
from viva_sitl.dynamics.rotation import wrap_pi
from viva_sitl.dynamics.state import EavCommand, EavState, vec3

_E3 = np.array([0.0, 0.0, 1.0])


def disturbance_force_n(
    state: EavState, wind: WindParams, params: EavParams, rng: np.random.Generator | None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """xi_k: drag of the vehicle relative to the air (mean wind + OU gust) plus white force noise.

    Returns (force_ned_n, next_gust_ned_m_s). Draws from `rng` only when a random term is enabled, so a
    disturbance-free run never consumes random numbers.
    """
    gust = state.gust_ned_m_s
    if wind.gust_std_m_s > 0.0:
        if rng is None:
            raise ValueError("gusts need a numpy Generator")
        a = math.exp(-params.dt_s / wind.gust_tau_s)
        gust = a * gust + wind.gust_std_m_s * math.sqrt(1.0 - a * a) * rng.standard_normal(3)
    air_ned_m_s = np.asarray(wind.mean_wind_ned_m_s, dtype=np.float64) + gust
    # The drag term of the model acts on ground velocity; wind adds k_d * v_air so drag acts on airspeed.
    force = params.drag_kd_n_s_m * air_ned_m_s
    if wind.force_noise_std_n > 0.0:
        if rng is None:
            raise ValueError("force noise needs a numpy Generator")
        force = force + wind.force_noise_std_n * rng.standard_normal(3)
    return force, vec3(gust)


def _axis_step(err_rad: float, tau_s: float, max_rate_deg_s: float, dt_s: float) -> float:
    """One step of an attitude axis: first order towards the command (exact for a constant command), the change
    clipped to the rate limit (PX4: rate setpoint = MC_*_P x error, constrained to MC_*RATE_MAX)."""
    d = err_rad if tau_s <= 0.0 else (1.0 - math.exp(-dt_s / tau_s)) * err_rad
    if max_rate_deg_s > 0.0:
        lim = math.radians(max_rate_deg_s) * dt_s
        d = max(-lim, min(lim, d))
    return d


def _attitude_response(state: EavState, cmd: EavCommand, params: EavParams) -> NDArray[np.float64]:
    """The attitude reached this step. Ideal (the paper): the command. Otherwise PX4's attitude controller over an
    ideal rate loop, per axis: first order towards the command, the change clipped to the rate limit. As PX4's
    reduced-attitude control, the tilt (thrust direction) is tracked apart from the heading: the tilt is lagged as a
    NED-fixed (forward, right) pair, so a yaw still under way never swings the thrust off its commanded direction
    (small-angle composition; exact per axis while the heading is constant)."""
    return np.array(_attitude_rpy(state, cmd, params))


_AxisGains = tuple[
    float | None, float | None
]  # (1 - exp(-dt/tau), None: tau <= 0; rad per step, None: unlimited)


def _axis_gains(tau_s: float, max_rate_deg_s: float, dt_s: float) -> _AxisGains:
    """_axis_step's two per-parameter factors, computed as _axis_step computes them."""
    k = None if tau_s <= 0.0 else 1.0 - math.exp(-dt_s / tau_s)
    lim = math.radians(max_rate_deg_s) * dt_s if max_rate_deg_s > 0.0 else None
    return k, lim


def _axis_step_gains(err_rad: float, gains: _AxisGains) -> float:
    """_axis_step with its factors precomputed (the same operations on the same doubles)."""
    k, lim = gains
    d = err_rad if k is None else k * err_rad
    if lim is not None:
        d = max(-lim, min(lim, d))
    return d


# the last EavParams seen and its (ideal attitude, yaw gains, roll/pitch gains): one tuple, swapped atomically; the
# params object is frozen and held here, so identity means the same values
_attitude_cache: tuple[EavParams, tuple[bool, _AxisGains, _AxisGains]] | None = None


def _attitude_consts(params: EavParams) -> tuple[bool, _AxisGains, _AxisGains]:
    global _attitude_cache
    cached = _attitude_cache
    if cached is not None and cached[0] is params:
        return cached[1]
    dt = params.dt_s
    consts = (
        params.ideal_attitude,
        _axis_gains(params.yaw_tau_s, params.max_yaw_rate_deg_s, dt),
        _axis_gains(params.attitude_tau_s, params.max_roll_pitch_rate_deg_s, dt),
    )
    _attitude_cache = (params, consts)
    return consts


def _attitude_rpy(state: EavState, cmd: EavCommand, params: EavParams) -> tuple[float, float, float]:
    """_attitude_response as (roll, pitch, yaw) floats."""
    roll = max(-params.max_tilt_rad, min(params.max_tilt_rad, cmd.roll_rad))
    pitch = max(-params.max_tilt_rad, min(params.max_tilt_rad, cmd.pitch_rad))
    ideal, yaw_gains, tilt_gains = _attitude_consts(params)
    if ideal:
        return float(roll), float(pitch), wrap_pi(cmd.yaw_rad)
    r0, p0, y0 = state.att_rpy_rad.tolist()
    y1 = wrap_pi(y0 + _axis_step_gains(wrap_pi(cmd.yaw_rad - y0), yaw_gains))
    d0, dc = wrap_pi(y0 - y1), wrap_pi(cmd.yaw_rad - y1)
    if d0 == 0.0 and dc == 0.0:  # heading steady: roll and pitch are independent axes
        fwd0, right0, fwd_c, right_c = -p0, r0, -pitch, roll
    else:  # tilt pairs (forward = -pitch, right = roll) seen from the new heading y1
        c0, s0 = math.cos(d0), math.sin(d0)
        cc, sc = math.cos(dc), math.sin(dc)
        fwd0, right0 = c0 * -p0 - s0 * r0, s0 * -p0 + c0 * r0
        fwd_c, right_c = cc * -pitch - sc * roll, sc * -pitch + cc * roll
    fwd1 = fwd0 + _axis_step_gains(fwd_c - fwd0, tilt_gains)
    right1 = right0 + _axis_step_gains(right_c - right0, tilt_gains)
    return float(right1), float(-fwd1), float(y1)


def paper_update(
    pos_km1: NDArray[np.float64],
    pos_km2: NDArray[np.float64],
    rot_body_to_ned_k: NDArray[np.float64],
    thrust_n: float,
    xi_n: NDArray[np.float64],
    params: EavParams,
) -> NDArray[np.float64]:
    """One application of the paper's equation in NED (no ground contact)."""
    dt = params.dt_s
    m = params.mass_kg
    force = (
        -rot_body_to_ned_k @ _E3 * thrust_n
        + m * params.gravity_m_s2 * _E3
        - (params.drag_kd_n_s_m / dt) * (pos_km1 - pos_km2)
        + xi_n
    )
    return np.asarray(2.0 * pos_km1 - pos_km2 + (dt * dt / m) * force, dtype=np.float64)


def _ro3(x: float, y: float, z: float) -> NDArray[np.float64]:
    """vec3 of three floats (read-only float64), without vec3's generic conversion."""
    a = np.array((x, y, z))
    a.flags.writeable = False
    return a


def step(
    state: EavState,
    cmd: EavCommand,
    params: EavParams,
    rng: np.random.Generator | None = None,
) -> EavState:
    """Advance the EAV by one step of params.dt_s. Pure: same inputs (and rng state) -> same output.

    The arithmetic of rot_body_to_ned, disturbance_force_n and paper_update on Python floats, axis by axis, in their
    order of operations (the same IEEE doubles, so the same bits; a 3-vector numpy op costs ~1 us, a float op ~30 ns).
    """
    if not (
        math.isfinite(cmd.roll_rad)
        and math.isfinite(cmd.pitch_rad)
        and math.isfinite(cmd.yaw_rad)
        and math.isfinite(cmd.thrust_n)
    ):
        raise ValueError(f"EAV command must be finite, got {cmd}")
    thrust = max(0.0, min(params.max_thrust_n, cmd.thrust_n))
    roll, pitch, yaw = _attitude_rpy(state, cmd, params)
    # the body z column of rot_body_to_ned(roll, pitch, yaw): R @ e3 (the other columns meet e3's zeros)
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    r02 = cy * sp * cr + sy * sr
    r12 = sy * sp * cr - cy * sr
    r22 = cp * cr
    # xi_k (disturbance_force_n)
    wind = params.wind
    dt = params.dt_s
    gust_arr = state.gust_ned_m_s
    gx, gy, gz = gust_arr.tolist()
    if (
        gust_arr.flags.writeable
    ):  # (states from EavState.at_rest and step are read-only: carried over as they are)
        gust_arr = _ro3(gx, gy, gz)
    if wind.gust_std_m_s > 0.0:
        if rng is None:
            raise ValueError("gusts need a numpy Generator")
        a = math.exp(-dt / wind.gust_tau_s)
        k = wind.gust_std_m_s * math.sqrt(1.0 - a * a)
        nx, ny, nz = rng.standard_normal(3).tolist()
        gx, gy, gz = a * gx + k * nx, a * gy + k * ny, a * gz + k * nz
        gust_arr = _ro3(gx, gy, gz)
    mw = wind.mean_wind_ned_m_s
    kd = params.drag_kd_n_s_m
    xi_x, xi_y, xi_z = kd * (float(mw[0]) + gx), kd * (float(mw[1]) + gy), kd * (float(mw[2]) + gz)
    if wind.force_noise_std_n > 0.0:
        if rng is None:
            raise ValueError("force noise needs a numpy Generator")
        nx, ny, nz = rng.standard_normal(3).tolist()
        fs = wind.force_noise_std_n
        xi_x, xi_y, xi_z = xi_x + fs * nx, xi_y + fs * ny, xi_z + fs * nz
    # paper_update
    m = params.mass_kg
    mg = m * params.gravity_m_s2
    kd_dt = kd / dt
    kf = dt * dt / m
    pos_arr = state.pos_ned_m
    p1x, p1y, p1z = pos_arr.tolist()
    p2x, p2y, p2z = state.prev_pos_ned_m.tolist()
    fx = -r02 * thrust + 0.0 - kd_dt * (p1x - p2x) + xi_x
    fy = -r12 * thrust + 0.0 - kd_dt * (p1y - p2y) + xi_y
    fz = -r22 * thrust + mg - kd_dt * (p1z - p2z) + xi_z
    nx_, ny_, nz_ = 2.0 * p1x - p2x + kf * fx, 2.0 * p1y - p2y + kf * fy, 2.0 * p1z - p2z + kf * fz

    landed = False
    touchdown = state.touchdown_speed_m_s
    ground = params.ground_z_ned_m
    if nz_ >= ground:
        # Ground contact: the vehicle cannot sink below the ground; contact kills velocity (no bounce, no slide).
        if not state.landed:
            step_m = np.array((nx_, ny_, nz_)) - pos_arr
            touchdown = float(np.linalg.norm(step_m / dt))
        net_up_n = float(-r22 * thrust) - mg
        new_pos = prev_pos = _ro3(p1x, p1y, float(ground))
        landed = net_up_n <= 1e-9
        # not landed: lift-off this step, on the ground plane with no downward velocity, but not "landed"
    else:
        new_pos = _ro3(nx_, ny_, nz_)
        # X_{k-1} becomes X_{k-2}: the same read-only array
        prev_pos = pos_arr if not pos_arr.flags.writeable else _ro3(p1x, p1y, p1z)
    # every field given: the constructor directly (dataclasses.replace walks the fields; this runs at 250 Hz)
    return type(state)(
        time_s=state.time_s + dt,
        step=state.step + 1,
        pos_ned_m=new_pos,
        prev_pos_ned_m=prev_pos,
        att_rpy_rad=_ro3(roll, pitch, yaw),
        thrust_n=thrust,
        gust_ned_m_s=gust_arr,
        landed=landed,
        touchdown_speed_m_s=touchdown,
        dt_s=dt,
    )
