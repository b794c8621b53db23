"""Manual modes from MANUAL_CONTROL (QGroundControl's joystick): Manual/Stabilized (sticks = tilt, throttle =
thrust), Altitude (throttle = climb rate, centred = hold altitude), Position (sticks = velocity, centred = hold)."""

from __future__ import annotations

import math

import numpy as np

from viva_sitl.autopilot.context import FlightContext
from viva_sitl.autopilot.control import TrajectorySetpoint
from viva_sitl.autopilot.setpoints import check_manual_input, deadzone, rot_yaw, throttle_to_thrust_norm
from viva_sitl.autopilot.tasks.common import NAN, idle, limits, run_position, thrust_from_norm
from viva_sitl.autopilot.types import ACCEPTED, CommandResult, FlightMode, ManualInput, Outcome
from viva_sitl.dynamics import EavCommand, EavParams, EavState, wrap_pi

MANUAL_DEADZONE = 0.05  # stick deadzone (fraction of full travel)
THROTTLE_DEADZONE = 0.1  # around mid-stick for climb-rate modes
HOLD_LOCK_SPEED_M_S = 0.3
MANUAL_MODES = frozenset({FlightMode.MANUAL, FlightMode.STABILIZED, FlightMode.ALTCTL, FlightMode.POSCTL})


class ManualTask:
    def __init__(self, ctx: FlightContext) -> None:
        self.ctx = ctx
        self.input: ManualInput | None = None
        self.last_s = -math.inf  # when the last MANUAL_CONTROL arrived
        self.hold_xy: tuple[float, float] | None = None
        self.hold_z: float | None = None

    def fresh(self, now_s: float) -> bool:
        return self.input is not None and now_s - self.last_s <= self.ctx.params.get("COM_RC_LOSS_T")

    def set_input(self, now_s: float, manual: ManualInput) -> Outcome:
        try:
            check_manual_input(manual)
        except ValueError as e:
            return Outcome(CommandResult.DENIED, str(e))
        self.input = manual
        self.last_s = now_s
        return ACCEPTED

    def activate(self, now_s: float) -> None:
        self.hold_xy = None
        self.hold_z = None
        self.ctx.yaw_sp = self.ctx.yaw

    def update(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        ctx = self.ctx
        p = ctx.params
        m = self.input if self.input is not None else ManualInput(0.0, 0.0, 0.5, 0.0)
        x = deadzone(m.x, MANUAL_DEADZONE)
        y = deadzone(m.y, MANUAL_DEADZONE)
        r = deadzone(m.r, MANUAL_DEADZONE)
        ctx.yaw_sp = wrap_pi(ctx.yaw_sp + r * math.radians(p.get("MPC_MAN_Y_MAX")) * dt)
        pos = np.asarray(state.pos_ned_m, dtype=np.float64)
        vel = np.asarray(state.vel_ned_m_s, dtype=np.float64)
        mode = ctx.mode
        if mode in (FlightMode.MANUAL, FlightMode.STABILIZED):
            tilt = math.radians(p.get("MPC_MAN_TILT_MAX"))
            hover = p.get("MPC_THR_HOVER")
            thrust = thrust_from_norm(ctx, throttle_to_thrust_norm(m.z, hover), eav)
            if state.landed and thrust <= eav.hover_thrust_n:
                return EavCommand(0.0, 0.0, ctx.yaw_sp, thrust)
            return EavCommand(y * tilt, -x * tilt, ctx.yaw_sp, thrust)
        # Vertical: throttle = climb rate, centred = altitude hold.
        climb = deadzone((m.z - 0.5) * 2.0, THROTTLE_DEADZONE)
        if climb == 0.0:
            if self.hold_z is None and abs(vel[2]) < HOLD_LOCK_SPEED_M_S:
                self.hold_z = float(pos[2])
            z_pos, z_vel = (self.hold_z, NAN) if self.hold_z is not None else (NAN, 0.0)
        else:
            self.hold_z = None
            z_pos = NAN
            z_vel = -climb * p.get("MPC_Z_VEL_MAX_UP") if climb > 0 else -climb * p.get("MPC_Z_VEL_MAX_DN")
        if state.landed and climb <= 0.0:
            self.hold_xy = None
            self.hold_z = None
            ctx.ctrl.reset()
            return idle(ctx)
        if mode == FlightMode.ALTCTL:
            sp = TrajectorySetpoint(pos_ned_m=(NAN, NAN, z_pos), vel_ned_m_s=(NAN, NAN, z_vel),
                                    acc_ned_m_s2=(0.0, 0.0, NAN))  # fmt: skip
            cmd = run_position(ctx, dt, state, sp, limits(ctx, xy=p.get("MPC_VEL_MANUAL"), auto=False), eav,
                               None, 0.0)  # fmt: skip
            tilt = math.radians(p.get("MPC_MAN_TILT_MAX"))
            roll, pitch = y * tilt, -x * tilt
            up = cmd.thrust_n * math.cos(cmd.roll_rad) * math.cos(cmd.pitch_rad)
            thrust = up / max(0.2, math.cos(roll) * math.cos(pitch))
            return EavCommand(roll, pitch, ctx.yaw_sp, thrust)
        # POSCTL: sticks = velocity in the heading frame, centred = position hold.
        vmax = p.get("MPC_VEL_MANUAL")
        if x == 0.0 and y == 0.0:
            if self.hold_xy is None and math.hypot(vel[0], vel[1]) < HOLD_LOCK_SPEED_M_S:
                self.hold_xy = (float(pos[0]), float(pos[1]))
            if self.hold_xy is not None:
                xy_pos, xy_vel = self.hold_xy, (NAN, NAN)
            else:
                xy_pos, xy_vel = (NAN, NAN), (0.0, 0.0)
        else:
            self.hold_xy = None
            xy_pos = (NAN, NAN)
            xy_vel = rot_yaw(ctx.yaw_sp, (x * vmax, y * vmax))
        sp = TrajectorySetpoint(
            pos_ned_m=(xy_pos[0], xy_pos[1], z_pos), vel_ned_m_s=(xy_vel[0], xy_vel[1], z_vel)
        )
        return run_position(ctx, dt, state, sp, limits(ctx, xy=vmax, auto=False), eav, None, 0.0)
