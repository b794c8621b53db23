"""Projection math of the VAC: pinhole K, camera rotation, ground-plane homographies from the full pose (pure).

Frames: world NED (ground plane z = 0, vehicle above it at z < 0), body FRD, camera x right / y down / z optical.
Pixel (u, v): u right, v down, pixel centres at integers, so the principal point of a W x H image is
((W - 1) / 2, (H - 1) / 2) and the FoV spans the pixel edges (-0.5 .. W - 0.5), as in `FootageGeometry`.

    R_nc = R_nb(mount-dependent attitude) @ R_bc        camera axes in NED
    C    = pos_ned + R_nb(full attitude) @ cam_pos_body_m   camera centre (NED)
    pixel ~ K R_nc^T (X - C)                                 for a world point X (NED)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from viva_sitl.camera.params import CameraParams, Mount
from viva_sitl.dynamics.rotation import rot_body_to_ned
from viva_sitl.footage.geometry import FootageGeometry

F64 = NDArray[np.float64]

# Default nadir mount R^b_v0: columns are the camera axes in FRD: x_cam = +y_body, y_cam = -x_body, z_cam = +z_body.
NADIR_CAM_ROT_BODY: F64 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

# The ground homography needs the camera strictly above the ground: a camera at or below z = 0 (a vehicle resting on
# the ground with the camera at its origin) is treated as this high above it. Hand-written because no library has it.
MIN_CAMERA_HEIGHT_M = 0.01


def _vec3(name: str, value: ArrayLike) -> F64:
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    # the finiteness test on the three Python floats: the renderer calls this ~7 times per view, where
    # np.all(np.isfinite(a)) costs ~3 us against ~0.3 us
    if a.shape != (3,) or not all(map(math.isfinite, a.tolist())):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    return a


def camera_intrinsics(params: CameraParams) -> F64:
    """3x3 pinhole K (pixels) of the VAC."""
    w, h = params.width_px, params.height_px
    fx = (w / 2.0) / math.tan(math.radians(params.hfov_deg) / 2.0)
    fy = (h / 2.0) / math.tan(math.radians(params.vfov_effective_deg) / 2.0)
    return np.array([[fx, 0.0, (w - 1) / 2.0], [0.0, fy, (h - 1) / 2.0], [0.0, 0.0, 1.0]])


def mount_cam_rot_body(params: CameraParams) -> F64:
    """R^b_v of the mount at level attitude: the nadir default rotated by the mount_*_deg offsets."""
    off = rot_body_to_ned(
        math.radians(params.mount_roll_deg),
        math.radians(params.mount_pitch_deg),
        math.radians(params.mount_yaw_deg),
    )
    return np.asarray(off @ NADIR_CAM_ROT_BODY, dtype=np.float64)


def cam_rot_ned(params: CameraParams, att_rpy_rad: ArrayLike) -> F64:
    """R_nc: camera axes (x right, y down, z optical) expressed in NED, for the vehicle attitude (roll, pitch, yaw)."""
    roll, pitch, yaw = _vec3("att_rpy_rad", att_rpy_rad)
    if params.mount is Mount.GIMBAL:
        r_nb = rot_body_to_ned(0.0, 0.0, yaw)  # the gimbal cancels roll and pitch; yaw follows the body
    else:
        r_nb = rot_body_to_ned(roll, pitch, yaw)
    return np.asarray(r_nb @ mount_cam_rot_body(params), dtype=np.float64)


def camera_extrinsics(params: CameraParams, att_rpy_rad: ArrayLike | None = None) -> tuple[F64, F64]:
    """(R^b_v, T^b_v): camera axes in FRD (3x3) and camera position in FRD (m).

    For a gimbal the camera's rotation relative to the body depends on the attitude: pass `att_rpy_rad` to get the
    actual one (without it, the level-attitude mount rotation is returned).
    """
    pos = np.asarray(params.cam_pos_body_m, dtype=np.float64)
    if att_rpy_rad is None or params.mount is Mount.FIXED:
        return mount_cam_rot_body(params), pos
    roll, pitch, yaw = _vec3("att_rpy_rad", att_rpy_rad)
    r_nb = rot_body_to_ned(roll, pitch, yaw)
    return np.asarray(r_nb.T @ cam_rot_ned(params, att_rpy_rad), dtype=np.float64), pos


def camera_center_ned(params: CameraParams, pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike) -> F64:
    """Camera centre in NED: the vehicle position plus the body-fixed lever arm (full attitude, any mount)."""
    pos = _vec3("pos_ned_m", pos_ned_m)
    roll, pitch, yaw = _vec3("att_rpy_rad", att_rpy_rad)
    return np.asarray(
        pos + rot_body_to_ned(roll, pitch, yaw) @ np.asarray(params.cam_pos_body_m), dtype=np.float64
    )


def frame_camera_fields(params: CameraParams, att_rpy_rad: ArrayLike | None = None) -> dict[str, object]:
    """`FrameMeta` keyword arguments intrinsics_k, cam_rot_body, cam_pos_body_m (tuples of floats)."""
    k = camera_intrinsics(params)
    r, t = camera_extrinsics(params, att_rpy_rad)
    return {
        "intrinsics_k": tuple(tuple(float(v) for v in row) for row in k),
        "cam_rot_body": tuple(tuple(float(v) for v in row) for row in r),
        "cam_pos_body_m": (float(t[0]), float(t[1]), float(t[2])),
    }


def project_ned(
    points_ned: ArrayLike, pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike, params: CameraParams
) -> F64:
    """Analytic pinhole projection of world points (N, 3) NED to VAC pixels (N, 2); NaN for points behind the camera."""
    pts = np.asarray(points_ned, dtype=np.float64).reshape(-1, 3)
    c = camera_center_ned(params, pos_ned_m, att_rpy_rad)
    r_nc = cam_rot_ned(params, att_rpy_rad)
    xc = (pts - c) @ r_nc  # rows: R_nc^T (X - C)
    k = camera_intrinsics(params)
    out = np.full((pts.shape[0], 2), np.nan)
    front = xc[:, 2] > 1e-12
    z = xc[front, 2]
    out[front, 0] = k[0, 0] * xc[front, 0] / z + k[0, 2]
    out[front, 1] = k[1, 1] * xc[front, 1] / z + k[1, 2]
    return out


def ground_to_image_homography(pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike, params: CameraParams) -> F64:
    """3x3 H mapping homogeneous ground points (north_m, east_m, 1) on z = 0 to VAC pixels (u, v, 1).

    The third homogeneous coordinate of H @ g is the depth of g along the optical axis (positive: in front).
    """
    c = camera_center_ned(params, pos_ned_m, att_rpy_rad)
    c[2] = min(c[2], -MIN_CAMERA_HEIGHT_M)
    r_nc = cam_rot_ned(params, att_rpy_rad)
    # X_c = R^T (X - C) with X = (n, e, 0): columns are R^T e1, R^T e2 and -R^T C
    m = np.column_stack([r_nc.T[:, 0], r_nc.T[:, 1], -r_nc.T @ c])
    return np.asarray(camera_intrinsics(params) @ m, dtype=np.float64)


def footage_to_image_homography(
    geometry: FootageGeometry, pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike, params: CameraParams
) -> F64:
    """3x3 H mapping full-resolution footage pixels (u, v, 1) to VAC pixels (ideal pinhole, before distortion)."""
    return np.asarray(ground_to_image_homography(pos_ned_m, att_rpy_rad, params) @ geometry.px_to_ground)


def pixel_to_ground(
    pixels_uv: ArrayLike, pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike, params: CameraParams
) -> F64:
    """Ground points (N, 3) NED (z = 0) seen at VAC pixels (N, 2); NaN rows for rays at or above the horizon."""
    px = np.asarray(pixels_uv, dtype=np.float64).reshape(-1, 2)
    h_inv = np.linalg.inv(ground_to_image_homography(pos_ned_m, att_rpy_rad, params))
    g = np.column_stack([px, np.ones(len(px))]) @ h_inv.T
    out = np.full((len(px), 3), np.nan)
    ok = g[:, 2] > 1e-12  # positive: the ray meets the ground in front of the camera
    out[ok, 0] = g[ok, 0] / g[ok, 2]
    out[ok, 1] = g[ok, 1] / g[ok, 2]
    out[ok, 2] = 0.0
    return out


def image_corners_px(params: CameraParams) -> F64:
    """The outer corners of the VAC image (pixel edges), top-left, top-right, bottom-right, bottom-left."""
    w, h = params.width_px - 0.5, params.height_px - 0.5
    return np.array([[-0.5, -0.5], [w, -0.5], [w, h], [-0.5, h]])


def ground_footprint(pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike, params: CameraParams) -> F64 | None:
    """Ground NED corners (4, 3) of the VAC view (top-left, top-right, bottom-right, bottom-left), or None when a
    corner ray is at or above the horizon (the footprint is unbounded). Ignores lens distortion."""
    g = pixel_to_ground(image_corners_px(params), pos_ned_m, att_rpy_rad, params)
    if not np.all(np.isfinite(g)):
        return None
    return g


def footprint_px(
    geometry: FootageGeometry, camera: CameraParams, pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike
) -> list[list[float]] | None:
    """The VAC's ground footprint (4 corners, footage px; a trapezoid under tilt); None when a corner ray is at or
    above the horizon (the footprint is unbounded)."""
    try:
        g = ground_footprint(pos_ned_m, att_rpy_rad, camera)
    except ValueError:
        return None
    if g is None:
        return None
    return [list(geometry.ned_to_px(float(n), float(e))) for n, e, _ in g]


def clip_convex_polygon(poly_xy: F64, halfplanes: Sequence[F64]) -> F64:
    """Clip a convex polygon (N, 2) by half-planes a . (x, y, 1) >= 0 (Sutherland-Hodgman; hand-written: OpenCV's
    intersectConvexConvex needs bounded polygons, and these half-planes are unbounded)."""
    pts = np.array(poly_xy, dtype=np.float64)  # a copy: returned as is when nothing is clipped
    for a in halfplanes:
        if len(pts) == 0:
            break
        d = pts @ a[:2] + a[2]
        if np.all(d >= 0):
            continue  # every vertex inside: the loop below would rebuild the same polygon
        if np.all(d < 0):
            return np.empty((0, 2))  # every vertex outside: the loop below would keep nothing
        out: list[F64] = []
        n = len(pts)
        for i in range(n):
            j = (i + 1) % n
            if d[i] >= 0:
                out.append(pts[i])
            if (d[i] >= 0) != (d[j] >= 0):
                t = d[i] / (d[i] - d[j])
                out.append(pts[i] + t * (pts[j] - pts[i]))
        pts = np.array(out).reshape(-1, 2)
    return pts


def polygon_area(poly_xy: F64) -> float:
    """Shoelace area of a simple polygon (N, 2)."""
    if len(poly_xy) < 3:
        return 0.0
    x, y = poly_xy[:, 0], poly_xy[:, 1]
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0)
