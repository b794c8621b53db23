"""One vehicle loop: the simulator (EAV + VAC over footage), the PX4 parameters and the autopilot, stepped together.

    vehicle = Vehicle(SimConfig())                 # synthetic footage; cheap (no video, nothing rendered yet)
    vehicle.reset(seed=0, pos_ned_m=(0, 0, 0), yaw_rad=0.0)
    vehicle.autopilot.arm(vehicle.time_s); vehicle.autopilot.takeoff(vehicle.time_s, 5.0)
    state = vehicle.step(250)                      # 250 physics steps: autopilot.update -> EAV step, each
    frame = vehicle.render()                       # the VAC view at the current state

Free-running and headless: nothing here reads a clock or does I/O; the caller owns time (the app paces `step` with
clock.run_paced, tests and trials call it as fast as they like). The SIM_* parameters (mass, drag, wind, attitude
response) reach the physics before every step, so a PARAM_SET between two steps applies to the next one.

This is the only place that steps the autopilot and the physics together: the app, the MAVLink selftest vehicle, the
tests, the trials runner and the Gymnasium environment all drive a Vehicle.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from viva_sitl.autopilot import Autopilot, ParamStore
from viva_sitl.autopilot.failures import FailureType
from viva_sitl.camera import Mount
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavCommand, EavParams, EavState
from viva_sitl.footage import FootageSource
from viva_sitl.frame import RenderedFrame
from viva_sitl.geo import GeoOrigin
from viva_sitl.sim import MagnifiedRenderLike, Simulator

if TYPE_CHECKING:
    from viva_sitl.world import WorldModel

InsideFn = Callable[[float, float], bool]


log = logging.getLogger("viva_sitl.vehicle")


class Vehicle:
    """The simulator + ParamStore + Autopilot. `geofence`: True = the footage edge (Simulator.inside_footage),
    False = no fence (an open world), or any (north_m, east_m) -> bool test. `super_resolution`: the render hook
    for low, magnified views (viva_sitl.perception.sr.super_resolution_from_config(config) builds the one a config's
    [perception.sr] asks for; the caller builds it, so the core never imports perception); kept across resets."""

    def __init__(
        self,
        config: SimConfig | None = None,
        *,
        footage: str | Path | FootageSource | None = None,
        geofence: bool | InsideFn = True,
        params: ParamStore | None = None,
        region_render: bool = True,
        prefetch: bool = False,
        super_resolution: MagnifiedRenderLike | None = None,
    ) -> None:
        self.config = config or SimConfig()
        self.sim = Simulator(self.config, footage, region_render=region_render, prefetch=prefetch)
        self._world: WorldModel | Literal[False] | None = None  # footage ground truth, built on first use
        self._mount_camera = (
            self.sim.camera
        )  # the camera as configured (a gimbal's angles are applied on top)
        self._last_good_image: NDArray[np.uint8] | None = (
            None  # a frozen camera (injected failure) repeats it
        )
        self.params = params if params is not None else ParamStore()
        self.params.adopt("MAV_SYS_ID", self.config.mavlink.system_id)  # as PX4 SITL -i N
        for name, value in self.config.params:
            self.params.set(name, value)
            spec = self.params.spec(name)
            if not spec.in_range(value):  # stored as PX4 stores it; say what the vehicle will use
                log.warning("%s = %g is outside PX4's range [%g, %g]: stored, the vehicle uses %g",
                            name, value, spec.min, spec.max, self.params.get(name))  # fmt: skip
        if geofence is True:
            self.inside: InsideFn | None = self.sim.inside_footage
        elif geofence is False:
            self.inside = None
        else:
            self.inside = geofence
        self.autopilot = self._new_autopilot()
        self.sim.super_resolution = super_resolution
        self.autopilot.start(self.time_s, self.state)  # home and pre-arm checks valid before the first step
        self.steps = 0  # physics steps since construction (all resets included)
        self._applied: EavParams = self.sim.params

    # --- state -------------------------------------------------------------------------
    @property
    def state(self) -> EavState:
        return self.sim.state

    @property
    def time_s(self) -> float:
        return float(self.sim.state.time_s)

    @property
    def dt_s(self) -> float:
        """The physics step now in use (SIM_* parameters never change it; the config does)."""
        return self.sim.params.dt_s

    @property
    def geo(self) -> GeoOrigin:
        return self.sim.geo

    # --- loop ----------------------------------------------------------------------------
    def reset(
        self,
        seed: int | None = None,
        pos_ned_m: tuple[float, float, float] | None = None,
        yaw_rad: float | None = None,
        vel_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> EavState:
        """A fresh flight: the simulator reset (seeded disturbances and sensor noise, pose) and a new Autopilot
        (disarmed on the ground, or armed in Hold for an air start) on the same parameters, as after a reboot. The
        autopilot has seen the initial state: arming is possible before the first step."""
        state = self.sim.reset(seed, pos_ned_m, yaw_rad, vel_ned_m_s)
        self._last_good_image = None
        self.autopilot = self._new_autopilot()
        self.autopilot.start(state.time_s, state)
        self._sync_params()
        return state

    def _new_autopilot(self) -> Autopilot:
        """An Autopilot on these parameters; with a `gimbal` camera mount it gets a gimbal whose rest is the mount's
        configured angles (MAVLink convention: pitch -90 = the nadir mount)."""
        cam = self._mount_camera
        neutral = (cam.mount_pitch_deg - 90.0, cam.mount_yaw_deg) if cam.mount is Mount.GIMBAL else None
        ap = Autopilot(self.params, self.config.physics, inside=self.inside, gimbal_neutral_deg=neutral)
        ap.follow_track_lookup = self.track_position  # Follow Me of a ground-truth track (FLW_TGT_TRACK)
        return ap

    def track_position(self, track: int, t_s: float) -> tuple[float, float, float, float] | None:
        """(north, east, v_north, v_east) of the footage's ground-truth track `track` (viva_sitl.world's index) at
        sim time t_s, None when it is not there then (or the footage has no ground truth). The world is built on
        first use (it reads the footage's track files), once."""
        if self._world is None:
            try:
                from viva_sitl.world import world_from_source

                self._world = world_from_source(self.sim.footage)
            except Exception as exc:  # ground truth is an extra: say why once, follow nothing
                log.warning("Follow Me: no footage ground truth (%s)", exc)
                self._world = False
        if self._world is False or not math.isfinite(t_s):
            return None
        tracks = self._world.tracks

        def at(t: float) -> tuple[float, float] | None:
            objs = tracks.objects_at(t)
            hit = np.flatnonzero(objs.track == track)
            return (float(objs.ne_m[hit[0], 0]), float(objs.ne_m[hit[0], 1])) if hit.size else None

        now = at(t_s)
        if now is None:
            return None
        dt = max(1.0 / tracks.fps, 0.2)
        before = at(t_s - dt) if t_s - dt >= 0.0 else None
        if before is None:
            return now[0], now[1], 0.0, 0.0
        return now[0], now[1], (now[0] - before[0]) / dt, (now[1] - before[1]) / dt

    def _sync_params(self) -> None:
        new = self.autopilot.eav_params()  # cached on the parameter revision: an identity test per step
        if new is not self._applied:
            self._applied = new
            if new != self.sim.params:
                self.sim.set_params(new)

    def step(self, n: int = 1) -> EavState:
        """n physics steps, each: SIM_* parameters -> physics, autopilot.update(state) -> EAV step."""
        sim, ap = self.sim, self.autopilot
        for _ in range(n):
            self._sync_params()
            s = sim.state
            sim.step(ap.update(s.time_s, s))
        self.steps += n
        return sim.state

    def step_command(self, cmd: EavCommand, n: int = 1) -> EavState:
        """n physics steps holding `cmd`, the autopilot bypassed (direct attitude/thrust control, e.g. a gym agent)."""
        self._sync_params()
        self.steps += n
        return self.sim.step(cmd, n)

    # --- camera --------------------------------------------------------------------------
    def render(self, state: EavState | None = None, wall_time_s: float | None = None) -> RenderedFrame:
        """The VAC view; a `gimbal` mount first takes the angles the autopilot's gimbal items asked for. An injected
        camera failure (Autopilot.camera_fault) acts here, so every consumer sees it: STUCK repeats the last good
        image (frozen), WRONG and OFF give black images; the metadata always tells the true pose. OFF also makes
        `camera_dropped` True: the video path delivers no frame at all then."""
        self.apply_gimbal()
        frame = self.sim.render(state, wall_time_s=wall_time_s)
        fault = self.autopilot.camera_fault
        if fault is None:
            self._last_good_image = frame.image_bgr
            return frame
        if fault is FailureType.STUCK and self._last_good_image is not None:
            return RenderedFrame(self._last_good_image, frame.meta)
        if fault is FailureType.STUCK:  # frozen before any good frame: nothing to repeat
            self._last_good_image = frame.image_bgr
            return frame
        return RenderedFrame(np.zeros_like(frame.image_bgr), frame.meta)

    @property
    def camera_dropped(self) -> bool:
        """An injected camera failure of type OFF: the camera delivers no frames (the app's render step sends
        nothing to the video outputs and the frame socket)."""
        return self.autopilot.camera_fault is FailureType.OFF

    def apply_gimbal(self) -> None:
        """Point a `gimbal` camera mount where the mission's gimbal items (DO_MOUNT_CONTROL,
        DO_GIMBAL_MANAGER_PITCHYAW) asked: MAVLink pitch -90 (down) is the nadir mount, 0 looks at the horizon
        (pitch limited to [-90, 30] deg, a typical gimbal's range); yaw is relative to the nose, + right. Before any
        such item, and for a fixed mount, the configured mount angles stay."""
        base = self._mount_camera
        want = self.autopilot.gimbal_pitch_yaw_deg
        if base.mount is not Mount.GIMBAL or want is None:
            camera = base
        else:
            pitch_deg = min(max(want[0], -90.0), 30.0)
            camera = replace(base, mount_pitch_deg=pitch_deg + 90.0, mount_yaw_deg=want[1])
        if camera != self.sim.camera:
            self.sim.set_camera(camera)

    def inside_footage(self, north_m: float, east_m: float) -> bool:
        return self.sim.inside_footage(north_m, east_m)

    def close(self) -> None:
        self.sim.close()

    def __enter__(self) -> Vehicle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["InsideFn", "Vehicle"]
