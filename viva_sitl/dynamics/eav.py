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
from viva_sitl.dynamics.rotation import rot_body_to_ned, wrap_pi
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
    roll = max(-params.max_tilt_rad, min(params.max_tilt_rad, cmd.roll_rad))
    pitch = max(-params.max_tilt_rad, min(params.max_tilt_rad, cmd.pitch_rad))
    if params.ideal_attitude:
        return np.array([roll, pitch, wrap_pi(cmd.yaw_rad)])
    r0, p0, y0 = (float(a) for a in state.att_rpy_rad)
    dt = params.dt_s
    y1 = wrap_pi(y0 + _axis_step(wrap_pi(cmd.yaw_rad - y0), params.yaw_tau_s, params.max_yaw_rate_deg_s, dt))
    d0, dc = wrap_pi(y0 - y1), wrap_pi(cmd.yaw_rad - y1)
    if d0 == 0.0 and dc == 0.0:  # heading steady: roll and pitch are independent axes
        fwd0, right0, fwd_c, right_c = -p0, r0, -pitch, roll
    else:  # tilt pairs (forward = -pitch, right = roll) seen from the new heading y1
        c0, s0 = math.cos(d0), math.sin(d0)
        cc, sc = math.cos(dc), math.sin(dc)
        fwd0, right0 = c0 * -p0 - s0 * r0, s0 * -p0 + c0 * r0
        fwd_c, right_c = cc * -pitch - sc * roll, sc * -pitch + cc * roll
    tau, rate = params.attitude_tau_s, params.max_roll_pitch_rate_deg_s
    fwd1 = fwd0 + _axis_step(fwd_c - fwd0, tau, rate, dt)
    right1 = right0 + _axis_step(right_c - right0, tau, rate, dt)
    return np.array([right1, -fwd1, y1])


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


def step(
    state: EavState,
    cmd: EavCommand,
    params: EavParams,
    rng: np.random.Generator | None = None,
) -> EavState:
    """Advance the EAV by one step of params.dt_s. Pure: same inputs (and rng state) -> same output."""
    if not (
        math.isfinite(cmd.roll_rad)
        and math.isfinite(cmd.pitch_rad)
        and math.isfinite(cmd.yaw_rad)
        and math.isfinite(cmd.thrust_n)
    ):
        raise ValueError(f"EAV command must be finite, got {cmd}")
    thrust = max(0.0, min(params.max_thrust_n, cmd.thrust_n))
    att = _attitude_response(state, cmd, params)
    rot = rot_body_to_ned(float(att[0]), float(att[1]), float(att[2]))
    xi, gust = disturbance_force_n(state, params.wind, params, rng)
    new_pos = paper_update(state.pos_ned_m, state.prev_pos_ned_m, rot, thrust, xi, params)
    prev_pos = state.pos_ned_m

    landed = False
    touchdown = state.touchdown_speed_m_s
    ground = params.ground_z_ned_m
    if new_pos[2] >= ground:
        # Ground contact: the vehicle cannot sink below the ground; contact kills velocity (no bounce, no slide).
        if not state.landed:
            touchdown = float(np.linalg.norm((new_pos - prev_pos) / params.dt_s))
        net_up_n = float(-(rot @ _E3)[2] * thrust) - params.mass_kg * params.gravity_m_s2
        new_pos = np.array([prev_pos[0], prev_pos[1], ground])
        prev_pos = vec3(new_pos)
        landed = net_up_n <= 1e-9
        if not landed:
            # Lift-off this step: stay on the ground plane, with no downward velocity, but not "landed".
            pass
    # every field given: the constructor directly (dataclasses.replace walks the fields; this runs at 250 Hz)
    return type(state)(
        time_s=state.time_s + params.dt_s,
        step=state.step + 1,
        pos_ned_m=vec3(new_pos),
        prev_pos_ned_m=vec3(prev_pos),
        att_rpy_rad=vec3(att),
        thrust_n=thrust,
        gust_ned_m_s=gust,
        landed=landed,
        touchdown_speed_m_s=touchdown,
        dt_s=params.dt_s,
    )
