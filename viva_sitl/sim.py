"""The headless Python API: reset with a seed and a pose, step with a command, get the state and the VAC frame.

    sim = Simulator(SimConfig(), footage="synthetic")
    state = sim.reset(seed=0, pos_ned_m=(0, 0, -50), yaw_rad=0.0)
    state = sim.step(EavCommand(roll_rad=0, pitch_rad=0, yaw_rad=0, thrust_n=sim.params.hover_thrust_n))
    frame = sim.render()          # RenderedFrame: image_bgr + FrameMeta (pose, intrinsics, footage index)

Free-running: nothing here reads a clock. `render(state)` may be called from one worker thread while another
thread steps (states are frozen); the footage decoder and pyramid cache belong to the rendering thread.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from viva_sitl.camera import CameraParams, LazyPyramid, Renderer, camera_extrinsics, camera_intrinsics
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavCommand, EavParams, EavState, step
from viva_sitl.footage import FootageSource, open_footage
from viva_sitl.frame import FrameMeta, RenderedFrame
from viva_sitl.geo import GeoOrigin


def _tuple3(a: np.ndarray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


class Simulator:
    """One vehicle (the EAV) with its camera (the VAC) over one footage."""

    def __init__(
        self,
        config: SimConfig | None = None,
        footage: str | Path | FootageSource | None = None,
        camera: CameraParams | None = None,
    ) -> None:
        self.config = config or SimConfig()
        if isinstance(footage, str | Path) or footage is None:
            self.footage: FootageSource = open_footage(
                footage if footage is not None else self.config.footage
            )
        else:
            self.footage = footage
        self.camera = camera or self.config.camera
        self.renderer = Renderer(self.camera, self.footage.geometry)
        self.params: EavParams = self.config.physics
        self._pyramid_index = -1
        self._pyramid: LazyPyramid | None = None
        self._frame_counter = 0
        self.reset(self.config.seed)

    # --- geometry ------------------------------------------------------------------
    @property
    def geo(self) -> GeoOrigin:
        """NED origin on the ground (footage centre): the footage's geo-reference, else the configured home."""
        return self.footage.geometry.geo_origin or self.config.home or GeoOrigin()

    def inside_footage(self, north_m: float, east_m: float) -> bool:
        """True while the ground point under the vehicle is inside the footage (the geofence)."""
        return self.footage.geometry.contains_ned(north_m, east_m)

    # --- dynamics --------------------------------------------------------------------
    def reset(
        self,
        seed: int | None = None,
        pos_ned_m: tuple[float, float, float] | None = None,
        yaw_rad: float | None = None,
        vel_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> EavState:
        seq = np.random.SeedSequence(self.config.seed if seed is None else seed)
        physics_seq, camera_seq = seq.spawn(2)
        self.rng = np.random.default_rng(physics_seq)  # disturbances
        self.camera_rng = np.random.default_rng(camera_seq)  # sensor noise: rendering never perturbs physics
        pos = self.config.initial_pos_ned_m if pos_ned_m is None else pos_ned_m
        yaw = math.radians(self.config.initial_yaw_deg) if yaw_rad is None else yaw_rad
        self.state = EavState.at_rest(
            pos, yaw_rad=yaw, dt_s=self.params.dt_s, vel_ned_m_s=vel_ned_m_s,
            ground_z_ned_m=self.params.ground_z_ned_m,
        )  # fmt: skip
        self._frame_counter = 0
        return self.state

    def set_params(self, params: EavParams) -> None:
        """Swap physics parameters between steps (e.g. SIM_* parameters changed over MAVLink)."""
        if params.dt_s != self.params.dt_s:
            vel = self.state.vel_ned_m_s
            self.state = EavState(
                time_s=self.state.time_s, step=self.state.step, pos_ned_m=self.state.pos_ned_m,
                prev_pos_ned_m=self.state.pos_ned_m - vel * params.dt_s, att_rpy_rad=self.state.att_rpy_rad,
                thrust_n=self.state.thrust_n, gust_ned_m_s=self.state.gust_ned_m_s, landed=self.state.landed,
                touchdown_speed_m_s=self.state.touchdown_speed_m_s, dt_s=params.dt_s,
            )  # fmt: skip
        self.params = params

    def step(self, cmd: EavCommand, n: int = 1) -> EavState:
        """Advance n physics steps holding `cmd`."""
        s = self.state
        for _ in range(n):
            s = step(s, cmd, self.params, self.rng)
        self.state = s
        return s

    @property
    def time_s(self) -> float:
        return self.state.time_s

    # --- camera --------------------------------------------------------------------------
    def footage_frame(self, time_s: float) -> tuple[int, LazyPyramid]:
        """The footage frame shown at sim time t (deterministic, looping) and its cached pyramid."""
        index = self.footage.frame_index_at(time_s)
        if index != self._pyramid_index or self._pyramid is None:
            self._pyramid = LazyPyramid(self.footage.frame(index))
            self._pyramid_index = index
        return index, self._pyramid

    def render(self, state: EavState | None = None, wall_time_s: float | None = None) -> RenderedFrame:
        """Render the VAC view at `state` (default: the current state)."""
        s = self.state if state is None else state
        wall = time.time() if wall_time_s is None else wall_time_s
        index, pyramid = self.footage_frame(s.time_s)
        result = self.renderer.render(pyramid, s.pos_ned_m, s.att_rpy_rad, s.vel_ned_m_s, self.camera_rng)
        lat, lon, alt = self.geo.ned_to_global(*_tuple3(s.pos_ned_m))
        k = camera_intrinsics(self.camera)
        _, pos_bv = camera_extrinsics(self.camera)
        meta = FrameMeta(
            frame_counter=self._frame_counter,
            sim_time_s=s.time_s,
            wall_time_s=wall,
            pos_ned_m=_tuple3(s.pos_ned_m),
            att_rpy_rad=_tuple3(s.att_rpy_rad),
            vel_ned_m_s=_tuple3(s.vel_ned_m_s),
            footage_frame_index=index,
            width_px=self.camera.width_px,
            height_px=self.camera.height_px,
            intrinsics_k=tuple(tuple(float(v) for v in row) for row in k),
            cam_rot_body=tuple(tuple(float(v) for v in row) for row in result.cam_rot_body),  # gimbal-aware
            cam_pos_body_m=_tuple3(np.asarray(pos_bv)),
            coverage=float(result.coverage),
            lat_deg=lat,
            lon_deg=lon,
            alt_amsl_m=alt,
        )
        self._frame_counter += 1
        return RenderedFrame(result.image_bgr, meta)

    def close(self) -> None:
        self.footage.close()

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
