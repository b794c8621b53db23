"""The EAV: the paper's equation, equilibria, drag, seeded disturbances, ground contact."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from viva_sitl.dynamics import (
    EavCommand,
    EavParams,
    EavState,
    WindParams,
    rot_body_to_ned,
    step,
)
from viva_sitl.dynamics.rotation import euler_from_quat, euler_from_rot, quat_from_euler, wrap_pi

# NED <-> the paper's z-up world (north, west, up); FRD <-> FLU body. C is its own inverse.
C = np.diag([1.0, -1.0, -1.0])


def rot_x(a: float) -> np.ndarray:
    """Elementary rotation about x by a (right-handed, active)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def reference_body_to_ned(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """ZYX (yaw, pitch, roll) body-to-NED rotation composed from the elementary rotations, not from the package."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def paper_step_zup(x1, x2, roll, pitch, yaw, thrust, xi, m, kd, g, dt):
    """The paper's equation written independently in a z-up frame with thrust along body +z."""
    r_paper = C @ reference_body_to_ned(roll, pitch, yaw) @ C
    e3 = np.array([0.0, 0.0, 1.0])
    return 2 * x1 - x2 + dt**2 / m * (r_paper @ e3 * thrust - m * g * e3 - kd / dt * (x1 - x2) + xi)


def test_paper_preset_numbers() -> None:
    p = EavParams.paper()
    assert (p.mass_kg, p.drag_kd_n_s_m, p.gravity_m_s2) == (0.468, 0.15, 9.81)
    assert p.dt_s == pytest.approx(1 / 30)
    assert EavParams().rate_hz >= 250


@pytest.mark.parametrize("params", [EavParams.paper(), EavParams()], ids=["paper-30Hz", "default-250Hz"])
def test_step_matches_paper_equation(params: EavParams) -> None:
    rng = np.random.default_rng(7)
    state = EavState.at_rest((3.0, -2.0, -40.0), dt_s=params.dt_s, vel_ned_m_s=(1.0, 0.5, -0.3))
    x1 = C @ state.pos_ned_m
    x2 = C @ state.prev_pos_ned_m
    for _ in range(200):
        roll, pitch, yaw = rng.uniform(-0.5, 0.5, 3)
        thrust = float(rng.uniform(2.0, 7.0))
        state = step(state, EavCommand(roll, pitch, yaw, thrust), params)
        if params.ideal_attitude:  # the paper: R_k is the commanded attitude
            assert tuple(state.att_rpy_rad) == (roll, pitch, wrap_pi(yaw))
        # R_k is the attitude the airframe reached this step (the default airframe lags its command)
        r_k, p_k, y_k = (float(a) for a in state.att_rpy_rad)
        x0 = paper_step_zup(
            x1, x2, r_k, p_k, y_k, thrust, np.zeros(3), params.mass_kg, params.drag_kd_n_s_m,
            params.gravity_m_s2, params.dt_s,
        )  # fmt: skip
        assert np.max(np.abs(C @ state.pos_ned_m - x0)) < 1e-9
        x1, x2 = x0, x1


def test_hover_equilibrium() -> None:
    p = EavParams()
    s = EavState.at_rest((0, 0, -20), dt_s=p.dt_s)
    for _ in range(2500):
        s = step(s, EavCommand(0, 0, 0.3, p.hover_thrust_n), p)
    assert np.allclose(s.pos_ned_m, (0, 0, -20), atol=1e-9)
    assert np.allclose(s.vel_ned_m_s, 0, atol=1e-9)
    assert not s.landed


def test_free_fall_without_drag() -> None:
    p = EavParams(drag_kd_n_s_m=0.0)
    s = EavState.at_rest((0, 0, -100), dt_s=p.dt_s)
    n = 250  # 1 s
    for _ in range(n):
        s = step(s, EavCommand(0, 0, 0, 0.0), p)
    t = n * p.dt_s
    # Verlet-type recursion: z_k = z_0 + g dt^2 k(k+1)/2 from rest (X_{-1} = X_0), exact for constant force
    assert s.pos_ned_m[2] == pytest.approx(-100 + p.gravity_m_s2 * p.dt_s**2 * n * (n + 1) / 2, abs=1e-9)
    assert s.pos_ned_m[2] == pytest.approx(-100 + 0.5 * p.gravity_m_s2 * t * t, abs=0.03)
    assert s.vel_ned_m_s[2] == pytest.approx(p.gravity_m_s2 * t, rel=1e-9)


def test_drag_terminal_velocity() -> None:
    p = EavParams()
    s = EavState.at_rest((0, 0, -5000), dt_s=p.dt_s)
    for _ in range(250 * 60):
        s = step(s, EavCommand(0, 0, 0, 0.0), p)
    v_terminal = p.mass_kg * p.gravity_m_s2 / p.drag_kd_n_s_m
    assert s.vel_ned_m_s[2] == pytest.approx(v_terminal, rel=1e-3)


def test_tilt_accelerates_in_the_expected_direction() -> None:
    p = EavParams().with_ideal_attitude()  # the equation's signs, with the attitude exactly as commanded
    s = EavState.at_rest((0, 0, -20), dt_s=p.dt_s)
    tilt = math.radians(10)
    thrust = p.hover_thrust_n / math.cos(tilt)
    for _ in range(250):
        s = step(s, EavCommand(0.0, -tilt, math.pi / 2, thrust), p)  # nose down, facing east
    assert s.vel_ned_m_s[1] > 1.0  # moves east
    assert abs(s.vel_ned_m_s[0]) < 1e-9
    assert abs(s.vel_ned_m_s[2]) < 1e-9  # thrust compensates the tilt


def test_constant_wind_pushes_downwind() -> None:
    p = EavParams(wind=WindParams(mean_wind_ned_m_s=(0.0, 3.0, 0.0)))
    s = EavState.at_rest((0, 0, -20), dt_s=p.dt_s)
    for _ in range(250 * 120):
        s = step(s, EavCommand(0, 0, 0, p.hover_thrust_n), p)
    assert s.vel_ned_m_s[1] == pytest.approx(3.0, rel=1e-3)  # drifts with the air mass


def _rollout(seed: int, n: int = 2000) -> list[EavState]:
    p = EavParams(
        wind=WindParams(mean_wind_ned_m_s=(1.0, 0.0, 0.0), gust_std_m_s=1.5, force_noise_std_n=0.05)
    )
    rng = np.random.default_rng(seed)
    s = EavState.at_rest((0, 0, -30), dt_s=p.dt_s)
    out = []
    for k in range(n):
        s = step(s, EavCommand(0.05 * math.sin(k / 50), 0.02, 0.1, p.hover_thrust_n), p, rng)
        out.append(s)
    return out


def test_seeded_determinism_bit_identical() -> None:
    a, b, c = _rollout(42), _rollout(42), _rollout(43)
    for sa, sb in zip(a, b, strict=True):
        assert sa.pos_ned_m.tobytes() == sb.pos_ned_m.tobytes()
        assert sa.gust_ned_m_s.tobytes() == sb.gust_ned_m_s.tobytes()
    assert a[-1].pos_ned_m.tobytes() != c[-1].pos_ned_m.tobytes()


def test_random_disturbance_requires_a_generator() -> None:
    p = EavParams(wind=WindParams(gust_std_m_s=1.0))
    with pytest.raises(ValueError, match="Generator"):
        step(EavState.at_rest((0, 0, -5), dt_s=p.dt_s), EavCommand(0, 0, 0, 1.0), p, None)


def test_ground_contact_landing_and_touchdown_speed() -> None:
    p = EavParams()
    s = EavState.at_rest((0, 0, -2), dt_s=p.dt_s, vel_ned_m_s=(0.0, 0.0, 0.0))
    thrust = p.hover_thrust_n * 0.9
    touched_at = None
    for k in range(250 * 5):
        s = step(s, EavCommand(0, 0, 0, thrust), p)
        assert s.pos_ned_m[2] <= p.ground_z_ned_m + 1e-12  # never below ground
        if s.landed and touched_at is None:
            touched_at = k
    assert touched_at is not None
    assert s.landed and s.touchdown_speed_m_s is not None
    # constant 0.1 g downward (minus drag) over 2 m: speed is below the drag-free bound sqrt(2 a h)
    assert 0.5 < s.touchdown_speed_m_s < math.sqrt(2 * 0.1 * p.gravity_m_s2 * 2) + 1e-6
    assert np.allclose(s.vel_ned_m_s, 0)
    # full thrust lifts off again
    for _ in range(50):
        s = step(s, EavCommand(0, 0, 0, p.max_thrust_n), p)
    assert not s.landed and s.altitude_m > 0.0


def test_resting_on_ground_stays_landed() -> None:
    p = EavParams()
    s = EavState.at_rest(dt_s=p.dt_s)
    assert s.landed
    for _ in range(100):
        s = step(s, EavCommand(0, 0, 0, 0.0), p)
    assert s.landed and s.altitude_m == 0.0


def test_attitude_first_order_response() -> None:
    p = EavParams(attitude_tau_s=0.1)
    s = EavState.at_rest((0, 0, -10), dt_s=p.dt_s)
    for _ in range(25):  # one time constant
        s = step(s, EavCommand(0.2, 0.0, 0.0, p.hover_thrust_n), p)
    assert s.roll_rad == pytest.approx(0.2 * (1 - math.exp(-1)), rel=1e-6)


def _pitch_step(p: EavParams, pitch_cmd_rad: float, seconds: float) -> list[float]:
    s = EavState.at_rest((0, 0, -50), dt_s=p.dt_s)
    out = []
    for _ in range(round(seconds / p.dt_s)):
        s = step(s, EavCommand(0.0, pitch_cmd_rad, 0.0, p.hover_thrust_n), p)
        out.append(s.pitch_rad)
    return out


def test_default_airframe_attitude_is_px4_like() -> None:
    """PX4's defaults: tau = 1/MC_PITCH_P (6.5), rate limits MC_PITCHRATE_MAX 220, MC_YAWRATE_MAX 200 deg/s."""
    p = EavParams()
    assert p.attitude_tau_s == pytest.approx(1 / 6.5) and p.yaw_tau_s == pytest.approx(1 / 2.8)
    assert (p.max_roll_pitch_rate_deg_s, p.max_yaw_rate_deg_s) == (220.0, 200.0)
    assert not p.ideal_attitude
    # a small step (10 deg): never rate-limited (initial rate 10 deg / 0.154 s = 65 deg/s), 63 % after one tau
    small = math.radians(10.0)
    pitch = _pitch_step(p, small, 1.0)
    n_tau = next(i + 1 for i, v in enumerate(pitch) if v >= 0.632 * small)
    assert n_tau * p.dt_s == pytest.approx(p.attitude_tau_s, abs=2 * p.dt_s)
    assert pitch[0] < 0.05 * small  # not there in one step
    assert pitch[-1] == pytest.approx(small, rel=2e-3)  # within e^-6.5 after 1 s = 6.5 tau
    # a large step (50 deg): the rate limit (220 deg/s) governs first; 63 % takes longer than tau
    big = math.radians(50.0)
    pitch = _pitch_step(p, big, 1.5)
    rates = np.diff([0.0, *pitch]) / p.dt_s
    assert math.degrees(float(np.max(rates))) == pytest.approx(220.0, rel=1e-9)
    # 220 deg/s until the error is 220 deg/s x tau (33.8 deg), then first order down to the 37 % left (18.4 deg)
    rate_max, tau = 220.0, p.attitude_tau_s
    err_sat = rate_max * tau
    t_expected = (50.0 - err_sat) / rate_max + tau * math.log(err_sat / (0.368 * 50.0))
    n_tau = next(i + 1 for i, v in enumerate(pitch) if v >= 0.632 * big)
    assert n_tau * p.dt_s == pytest.approx(t_expected, abs=2 * p.dt_s)
    assert t_expected > 1.05 * tau  # slower than the unsaturated response
    assert pitch[-1] == pytest.approx(big, rel=1e-3)
    # yaw: slower, limited to 200 deg/s, and takes the short way round through +-pi
    s = EavState.at_rest((0, 0, -50), yaw_rad=math.radians(170.0), dt_s=p.dt_s)
    yaws = []
    for _ in range(round(0.5 / p.dt_s)):
        s = step(s, EavCommand(0.0, 0.0, math.radians(-170.0), p.hover_thrust_n), p)
        yaws.append(s.yaw_rad)
    assert all(abs(y) > math.radians(160.0) for y in yaws)  # never swings through 0
    assert abs(wrap_pi(yaws[-1] - math.radians(-170.0))) < math.radians(5.0)


def test_paper_preset_attitude_is_instant() -> None:
    p = EavParams.paper()
    assert p.ideal_attitude
    pitch = _pitch_step(p, math.radians(50.0), 0.2)
    assert pitch == [math.radians(50.0)] * len(pitch)  # the command, from the first step on
    assert EavParams().with_ideal_attitude().ideal_attitude


def test_attitude_params_validated() -> None:
    for key in ("attitude_tau_s", "yaw_tau_s", "max_roll_pitch_rate_deg_s", "max_yaw_rate_deg_s"):
        with pytest.raises(ValueError, match=key):
            EavParams(**{key: -1.0})
        with pytest.raises(ValueError, match=key):
            EavParams(**{key: math.inf})


def test_non_finite_command_rejected() -> None:
    p = EavParams()
    with pytest.raises(ValueError, match="finite"):
        step(EavState.at_rest(dt_s=p.dt_s), EavCommand(math.nan, 0, 0, 1.0), p)


def test_bad_params_rejected() -> None:
    with pytest.raises(ValueError, match="mass_kg"):
        EavParams(mass_kg=0.0)


def test_rotation_matches_an_independent_zyx_reference() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        r, p, y = rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), rng.uniform(-math.pi, math.pi)
        assert np.allclose(rot_body_to_ned(r, p, y), reference_body_to_ned(r, p, y), atol=1e-12), (r, p, y)
    # physical meaning, each axis alone: FRD body axes seen in NED
    quarter = math.pi / 2
    assert np.allclose(rot_body_to_ned(0, 0, quarter) @ (1, 0, 0), (0, 1, 0))  # yaw +90: nose points east
    assert np.allclose(rot_body_to_ned(0, quarter, 0) @ (1, 0, 0), (0, 0, -1))  # pitch +90: nose points up
    assert np.allclose(rot_body_to_ned(quarter, 0, 0) @ (0, 1, 0), (0, 0, 1))  # roll +90: right wing down


def test_quaternion_matches_the_rotation_matrix() -> None:
    """quat_from_euler against the matrix built from the quaternion's textbook formula."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        r, p, y = rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), rng.uniform(-math.pi, math.pi)
        w, x, q2, z = quat_from_euler(r, p, y)
        from_quat = np.array(
            [
                [1 - 2 * (q2 * q2 + z * z), 2 * (x * q2 - w * z), 2 * (x * z + w * q2)],
                [2 * (x * q2 + w * z), 1 - 2 * (x * x + z * z), 2 * (q2 * z - w * x)],
                [2 * (x * z - w * q2), 2 * (q2 * z + w * x), 1 - 2 * (x * x + q2 * q2)],
            ]
        )
        assert np.allclose(from_quat, reference_body_to_ned(r, p, y), atol=1e-12), (r, p, y)


def test_rotation_matches_scipy_when_available() -> None:
    spatial = pytest.importorskip("scipy.spatial.transform")
    rng = np.random.default_rng(5)
    for _ in range(50):
        r, p, y = rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), rng.uniform(-math.pi, math.pi)
        ref = spatial.Rotation.from_euler("ZYX", [y, p, r]).as_matrix()  # intrinsic z-y'-x''
        assert np.allclose(rot_body_to_ned(r, p, y), ref, atol=1e-12)


def test_rotation_round_trips() -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        r, p, y = rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(-3, 3)
        assert np.allclose(euler_from_rot(rot_body_to_ned(r, p, y)), (r, p, y))
        assert np.allclose(euler_from_quat(*quat_from_euler(r, p, y)), (r, p, y))


def test_paper_preset_reproduces_the_reference_implementation() -> None:
    """300 steps recorded from viva-safeland 0.2.0's own Drone.move (varied roll, pitch, yaw rate, thrust)."""
    golden = json.loads((Path(__file__).parent / "data" / "reference_golden_30hz.json").read_text())
    params = EavParams.paper(dt_s=1.0 / golden["fps"])
    state = EavState.at_rest(golden["start_ned_m"], dt_s=params.dt_s)
    worst = 0.0
    for roll, pitch, yaw, thrust, *pos in golden["rows"]:
        state = step(state, EavCommand(roll, pitch, yaw, thrust), params)
        worst = max(worst, float(np.max(np.abs(state.pos_ned_m - np.asarray(pos)))))
    assert len(golden["rows"]) == 300
    assert worst <= 1e-9
    # and the check is sensitive: a drag off by 1e-6 breaks it
    state = EavState.at_rest(golden["start_ned_m"], dt_s=params.dt_s)
    off = dataclasses.replace(params, drag_kd_n_s_m=0.15 + 1e-6)
    for roll, pitch, yaw, thrust, *_ in golden["rows"]:
        state = step(state, EavCommand(roll, pitch, yaw, thrust), off)
    assert float(np.max(np.abs(state.pos_ned_m - np.asarray(golden["rows"][-1][4:])))) > 1e-9
