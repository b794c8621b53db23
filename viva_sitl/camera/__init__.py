"""The Virtual Aerial Camera (VAC): a pinhole on the vehicle that sees the footage through a full-pose homography.

Public API:

    Mount                                   FIXED (rigid on the body, default) | GIMBAL (roll/pitch stabilised)
    CameraParams(width_px=640, height_px=480, hfov_deg=82.1, vfov_deg=None, mount=Mount.FIXED,
                 mount_roll_deg=0, mount_pitch_deg=0, mount_yaw_deg=0, cam_pos_body_m=(0, 0, 0),
                 fill_bgr=(255, 0, 255), antialias=True, lod_bias=0, trilinear=True, motion_blur=False,
                 exposure_s=0.01, noise_std=0, k1=0, k2=0)   frozen config ([camera] table)
    DEFAULT_FILL_BGR                        (255, 0, 255) magenta: pixels that see no footage

    camera_intrinsics(params) -> K (3, 3)
    camera_extrinsics(params, att_rpy_rad=None) -> (R^b_v (3, 3), T^b_v (3,))
    frame_camera_fields(params, att_rpy_rad=None) -> {intrinsics_k, cam_rot_body, cam_pos_body_m} for FrameMeta
    cam_rot_ned(params, att_rpy_rad) -> R_nc (3, 3);  camera_center_ned(params, pos_ned_m, att_rpy_rad) -> (3,)
    project_ned(points_ned (N, 3), pos_ned_m, att_rpy_rad, params) -> (N, 2) px (NaN behind the camera)
    pixel_to_ground(pixels_uv (N, 2), pos_ned_m, att_rpy_rad, params) -> (N, 3) NED (NaN above the horizon)
    ground_to_image_homography(pos_ned_m, att_rpy_rad, params) -> H: (north, east, 1) -> (u, v, 1)
    footage_to_image_homography(geometry, pos_ned_m, att_rpy_rad, params) -> H: footage px -> VAC px
    ground_footprint(pos_ned_m, att_rpy_rad, params) -> (4, 3) NED corners TL, TR, BR, BL, or None
    footprint_px(geometry, params, pos_ned_m, att_rpy_rad) -> the same 4 corners in footage px, or None

    build_pyramid(image_bgr, levels) -> [level0, level1, ...]      (2x box-filter mip-map, INTER_AREA)
    LazyPyramid(image_bgr).level(l)                                 (builds levels on first use, thread-safe)
    Renderer(params, geometry).render(pyramid, pos_ned_m, att_rpy_rad, vel_ned_m_s=None, rng=None) -> RenderResult
    RenderResult(image_bgr, coverage, homography, pyramid_level, footage_px_per_vac_px, cam_rot_body, lod_blend)
    render_view(source_image_bgr, geometry, params, pos_ned_m, att_rpy_rad) -> image_bgr

Conventions: NED world (ground z = 0, vehicle z < 0), FRD body, attitude (roll, pitch, yaw) rad body->NED (ZYX);
positive pitch = nose up, positive yaw = clockwise seen from above. Default nadir mount: the nose points to the top
of the image. With the fixed mount a nose-down pitch turns the belly camera toward the ground behind.
"""

from viva_sitl.camera.effects import add_sensor_noise, apply_motion_blur, motion_blur_kernel
from viva_sitl.camera.params import DEFAULT_FILL_BGR, CameraParams, Mount
from viva_sitl.camera.projection import (
    NADIR_CAM_ROT_BODY,
    cam_rot_ned,
    camera_center_ned,
    camera_extrinsics,
    camera_intrinsics,
    footage_to_image_homography,
    footprint_px,
    frame_camera_fields,
    ground_footprint,
    ground_to_image_homography,
    pixel_to_ground,
    project_ned,
)
from viva_sitl.camera.pyramid import LazyPyramid, build_pyramid
from viva_sitl.camera.renderer import Renderer, RenderResult, render_view
from viva_sitl.imaging import max_pyramid_level

__all__ = [
    "DEFAULT_FILL_BGR",
    "NADIR_CAM_ROT_BODY",
    "CameraParams",
    "LazyPyramid",
    "Mount",
    "RenderResult",
    "Renderer",
    "add_sensor_noise",
    "apply_motion_blur",
    "build_pyramid",
    "cam_rot_ned",
    "camera_center_ned",
    "camera_extrinsics",
    "camera_intrinsics",
    "footage_to_image_homography",
    "footprint_px",
    "frame_camera_fields",
    "ground_footprint",
    "ground_to_image_homography",
    "max_pyramid_level",
    "motion_blur_kernel",
    "pixel_to_ground",
    "project_ned",
    "render_view",
]
