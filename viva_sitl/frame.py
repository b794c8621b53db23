"""A rendered VAC frame and the ground truth it was rendered at: the unit passed from camera to every video output."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class FrameMeta:
    frame_counter: int  # 0, 1, 2, ... per run, one per rendered frame
    sim_time_s: float  # simulation time of the pose the frame was rendered at
    wall_time_s: float  # time.time() when the pose was sampled (for glass-to-glass latency)
    pos_ned_m: tuple[float, float, float]  # vehicle position (NED, m; origin = footage centre on the ground)
    att_rpy_rad: tuple[float, float, float]  # vehicle attitude, FRD->NED (roll, pitch, yaw)
    vel_ned_m_s: tuple[float, float, float]
    footage_frame_index: int
    width_px: int
    height_px: int
    intrinsics_k: tuple[tuple[float, float, float], ...]  # 3x3 pinhole K of the VAC (pixels)
    # 3x3 R^b_v: camera axes (x right, y down, z optical) expressed in FRD
    cam_rot_body: tuple[tuple[float, float, float], ...]
    cam_pos_body_m: tuple[float, float, float]  # T^b_v: camera position in FRD (m)
    coverage: float  # fraction of VAC pixels that see footage (1 = all; < 1: part outside, filled)
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_amsl_m: float | None = None

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass(frozen=True)
class RenderedFrame:
    image_bgr: NDArray[np.uint8]  # (height, width, 3) uint8, BGR (OpenCV order)
    meta: FrameMeta
