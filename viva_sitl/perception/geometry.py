"""Image <-> ground for a companion that only has what the frame-and-pose socket sends (FrameMeta fields).

    h = ground_homography_from_meta(meta)              # (north, east, 1) on z = 0 -> (u, v, 1) pixel centres
    ne = image_to_ground(h, pixels_uv)                  # (k, 2) north/east, NaN above the horizon

Same convention as viva_sitl.camera.projection: X_cam = R_nc^T (X - C), R_nc = R_nb(att) @ cam_rot_body (which the
SITL sends gimbal-aware), C = pos + R_nb(att) @ cam_pos_body_m, pixel ~ K X_cam.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from viva_sitl.dynamics.rotation import rot_body_to_ned

F64 = NDArray[np.float64]
MIN_CAMERA_HEIGHT_M = 0.01


def ground_homography_from_meta(meta: Any) -> F64:
    """3x3 ground -> image homography from a FrameMeta (or any object / dict with its fields)."""

    def get(name: str) -> Any:
        return meta[name] if isinstance(meta, dict) else getattr(meta, name)

    k = np.asarray(get("intrinsics_k"), np.float64).reshape(3, 3)
    r_bc = np.asarray(get("cam_rot_body"), np.float64).reshape(3, 3)
    t_b = np.asarray(get("cam_pos_body_m"), np.float64).reshape(3)
    pos = np.asarray(get("pos_ned_m"), np.float64).reshape(3)
    roll, pitch, yaw = (float(v) for v in get("att_rpy_rad"))
    r_nb = rot_body_to_ned(roll, pitch, yaw)
    r_nc = r_nb @ r_bc
    c = pos + r_nb @ t_b
    c[2] = min(c[2], -MIN_CAMERA_HEIGHT_M)
    m = np.column_stack([r_nc.T[:, 0], r_nc.T[:, 1], -r_nc.T @ c])
    return np.asarray(k @ m, np.float64)


def image_to_ground(h_ground_to_image: F64, pixels_uv: ArrayLike) -> F64:
    """(k, 2) north/east seen at pixel centres (k, 2); NaN rows where the ray misses the ground."""
    px = np.asarray(pixels_uv, np.float64).reshape(-1, 2)
    g = np.column_stack([px, np.ones(len(px))]) @ np.linalg.inv(h_ground_to_image).T
    out = np.full((len(px), 2), np.nan)
    ok = g[:, 2] > 1e-12
    out[ok] = g[ok, :2] / g[ok, 2:3]
    return out
