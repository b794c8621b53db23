"""The Virtual Aerial Camera: projection math against independent oracles, and rendered images against references."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from viva_sitl.camera import (
    DEFAULT_FILL_BGR,
    CameraParams,
    LazyPyramid,
    Mount,
    Renderer,
    build_pyramid,
    cam_rot_ned,
    camera_extrinsics,
    camera_intrinsics,
    footage_to_image_homography,
    frame_camera_fields,
    ground_footprint,
    ground_to_image_homography,
    pixel_to_ground,
    project_ned,
    render_view,
)
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.frame import FrameMeta

SHARED = Path(__file__).resolve().parents[2] / "shared"
SONGDO = SHARED / "footage" / "songdo" / "00003.jpg"
DEG = math.pi / 180.0


# --- helpers ------------------------------------------------------------------------------------------------------
def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0**2 / mse)


def u8(img: object) -> np.ndarray:
    """cv2 results typed as uint8 arrays (OpenCV's stubs are loose)."""
    assert isinstance(img, np.ndarray)
    return np.asarray(img, dtype=np.uint8)


def texture(h: int, w: int, seed: int) -> np.ndarray:
    """Colour texture with energy at every scale from 1 px to 128 px (aliases visibly when undersampled)."""
    rng = np.random.default_rng(seed)
    acc = np.zeros((h, w, 3), np.float32)
    for s in (1, 2, 4, 8, 16, 32, 64, 128):
        n = rng.standard_normal(((h + s - 1) // s + 1, (w + s - 1) // s + 1, 3)).astype(np.float32)
        acc += cv2.resize(n, (w, h), interpolation=cv2.INTER_LINEAR if s > 1 else cv2.INTER_NEAREST)
    acc = (acc - acc.mean()) / acc.std()
    return np.clip(128.0 + 45.0 * acc, 0, 240).astype(np.uint8)  # <= 240: never the magenta fill


def blob_footage(geom: FootageGeometry, ground_ne: list[tuple[float, float]], sigma_px: float) -> np.ndarray:
    """Black footage with white Gaussian blobs centred (sub-pixel) on the given ground points."""
    img = np.zeros((geom.height_px, geom.width_px), np.float32)
    r = int(4 * sigma_px) + 2
    for n, e in ground_ne:
        u, v = geom.ned_to_px(n, e)
        u0, v0 = round(u), round(v)
        ys, xs = np.mgrid[v0 - r : v0 + r + 1, u0 - r : u0 + r + 1]
        g = np.exp(-((xs - u) ** 2 + (ys - v) ** 2) / (2 * sigma_px**2))
        img[v0 - r : v0 + r + 1, u0 - r : u0 + r + 1] += g
    return np.repeat(np.clip(img * 255.0, 0, 255).astype(np.uint8)[..., None], 3, axis=2)


def centroid(img_bgr: np.ndarray, uv: np.ndarray, r: int) -> np.ndarray:
    g = img_bgr[..., 1].astype(np.float64)  # green: 0 for the magenta fill, so fill never biases the centroid
    u0, v0 = round(uv[0]), round(uv[1])
    win = g[v0 - r : v0 + r + 1, u0 - r : u0 + r + 1]
    ys, xs = np.mgrid[v0 - r : v0 + r + 1, u0 - r : u0 + r + 1]
    return np.array([(win * xs).sum() / win.sum(), (win * ys).sum() / win.sum()])


def rot_zyx_cv(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body->NED rotation built independently of viva_sitl: Rz(yaw) Ry(pitch) Rx(roll) from Rodrigues vectors."""
    rz = cv2.Rodrigues(np.array([0.0, 0.0, yaw]))[0]
    ry = cv2.Rodrigues(np.array([0.0, pitch, 0.0]))[0]
    rx = cv2.Rodrigues(np.array([roll, 0.0, 0.0]))[0]
    return rz @ ry @ rx


def supersampled_reference(img, geom, params, pos, att, factor=8):
    """Area-averaged reference: plain warp at `factor` x the resolution (no aliasing there), then INTER_AREA down."""
    big = dataclasses.replace(params, width_px=params.width_px * factor, height_px=params.height_px * factor)
    m = np.linalg.inv(footage_to_image_homography(geom, pos, att, big))
    hi = cv2.warpPerspective(
        img, m, (big.width_px, big.height_px), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT, borderValue=tuple(float(c) for c in params.fill_bgr),
    )  # fmt: skip
    return cv2.resize(hi, (params.width_px, params.height_px), interpolation=cv2.INTER_AREA)


GEOM_1080 = FootageGeometry.from_fov(1920, 1080, recording_altitude_m=100.0, hfov_deg=82.1)


# --- parameters and frames --------------------------------------------------------------------------------------
def test_params_validation_and_defaults() -> None:
    p = CameraParams()
    assert (p.width_px, p.height_px, p.hfov_deg, p.mount) == (640, 480, 82.1, Mount.FIXED)
    assert p.fill_bgr == DEFAULT_FILL_BGR == (255, 0, 255)
    assert not (p.motion_blur or p.noise_std or p.k1 or p.k2)
    t = math.tan(82.1 * DEG / 2) * 480 / 640
    assert p.vfov_effective_deg == pytest.approx(2 * math.degrees(math.atan(t)))
    k = camera_intrinsics(p)
    assert k[0, 0] == pytest.approx(320 / math.tan(82.1 * DEG / 2)) and k[1, 1] == pytest.approx(k[0, 0])
    assert (k[0, 2], k[1, 2]) == (319.5, 239.5)
    assert camera_intrinsics(CameraParams(vfov_deg=50.0))[1, 1] == pytest.approx(240 / math.tan(25 * DEG))
    for bad in (
        {"width_px": 0},
        {"height_px": -1},
        {"width_px": 64.0},
        {"hfov_deg": math.nan},
        {"hfov_deg": 180.0},
        {"vfov_deg": 0.0},
        {"fill_bgr": (0, 0, 256)},
        {"fill_bgr": (0, 0)},
        {"cam_pos_body_m": (0.0, math.inf, 0.0)},
        {"noise_std": -1.0},
        {"exposure_s": math.nan},
        {"k1": math.nan},
        {"mount": "gimbal"},
    ):
        with pytest.raises(ValueError):
            CameraParams(**bad)  # type: ignore[arg-type]


def test_frame_meta_fields() -> None:
    p = CameraParams(cam_pos_body_m=(0.1, 0.0, 0.05))
    fields = frame_camera_fields(p)
    meta = FrameMeta(
        frame_counter=0, sim_time_s=0.0, wall_time_s=0.0, pos_ned_m=(0.0, 0.0, -10.0), att_rpy_rad=(0.0, 0.0, 0.0),
        vel_ned_m_s=(0.0, 0.0, 0.0), footage_frame_index=0, width_px=640, height_px=480, coverage=1.0,
        **fields,  # type: ignore[arg-type]
    )  # fmt: skip
    assert np.allclose(meta.intrinsics_k, camera_intrinsics(p))
    # default nadir mount: x_cam = body right, y_cam = body backward, z_cam = body down
    assert np.array_equal(np.array(meta.cam_rot_body), [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert meta.cam_pos_body_m == (0.1, 0.0, 0.05)
    # a gimbal's R^b_v follows the attitude: it keeps the camera level in NED
    g = CameraParams(mount=Mount.GIMBAL)
    att = (0.2, -0.3, 1.0)
    r_bv, _ = camera_extrinsics(g, att)
    assert np.allclose(rot_zyx_cv(*att) @ r_bv, cam_rot_ned(g, (0.0, 0.0, 1.0)))


# --- projection math ----------------------------------------------------------------------------------------------
def test_nadir_orientation_nose_up_in_image() -> None:
    p = CameraParams()
    pos = (0.0, 0.0, -50.0)
    uv = project_ned([[10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 0.0]], pos, (0, 0, 0), p)
    f = camera_intrinsics(p)[0, 0]
    assert np.allclose(uv[0], [319.5, 239.5 - f * 10 / 50])  # north (ahead) is up
    assert np.allclose(uv[1], [319.5 + f * 10 / 50, 239.5])  # east (right wing) is right
    assert np.allclose(uv[2], [319.5, 239.5])
    # behind the camera: NaN
    assert np.all(np.isnan(project_ned([[0.0, 0.0, -60.0]], pos, (0, 0, 0), p)))


def test_projection_matches_opencv_projectpoints() -> None:
    rng = np.random.default_rng(1)
    p = CameraParams(
        mount_pitch_deg=5.0, mount_roll_deg=-3.0, mount_yaw_deg=2.0, cam_pos_body_m=(0.2, -0.1, 0.15)
    )
    k = camera_intrinsics(p)
    r_bv0 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    r_bv = rot_zyx_cv(-3.0 * DEG, 5.0 * DEG, 2.0 * DEG) @ r_bv0  # mount offsets roll, pitch, yaw
    for _ in range(50):
        att = (rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-math.pi, math.pi))
        pos = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-150, -5)])
        r_nb = rot_zyx_cv(*att)
        r_nc = r_nb @ r_bv
        c = pos + r_nb @ np.array(p.cam_pos_body_m)
        rays_cam = np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-1, 1, 30), np.ones(30)])
        pts = c + 40.0 * rays_cam @ r_nc.T  # points in front of the camera
        rvec = cv2.Rodrigues(r_nc.T)[0]
        tvec = -r_nc.T @ c
        ref = cv2.projectPoints(pts.reshape(-1, 1, 3), rvec, tvec, k, None)[0].reshape(-1, 2)
        got = project_ned(pts, pos, att, p)
        assert np.max(np.abs(got - ref)) < 1e-6


def test_homography_reprojection_random_full_poses() -> None:
    """Ground points through the homographies (ground and footage->VAC) agree with the pinhole model < 0.5 px."""
    rng = np.random.default_rng(2)
    p = CameraParams(cam_pos_body_m=(0.05, 0.02, 0.1))
    worst = 0.0
    for _ in range(200):
        att = (rng.uniform(-0.7, 0.7), rng.uniform(-0.7, 0.7), rng.uniform(-math.pi, math.pi))
        pos = (rng.uniform(-40, 40), rng.uniform(-40, 40), rng.uniform(-120, -2))
        pix = np.column_stack([rng.uniform(0, 639, 40), rng.uniform(0, 479, 40)])
        ground = pixel_to_ground(pix, pos, att, p)
        seen = np.isfinite(ground[:, 0])
        ground = ground[seen]
        if len(ground) == 0:
            continue
        ref = project_ned(ground, pos, att, p)
        assert np.allclose(ref, pix[seen], atol=1e-6)  # pixel -> ground -> pixel round trip
        h = ground_to_image_homography(pos, att, p)
        q = np.column_stack([ground[:, :2], np.ones(len(ground))]) @ h.T
        assert np.all(q[:, 2] > 0)
        worst = max(worst, float(np.max(np.abs(q[:, :2] / q[:, 2:] - ref))))
        hf = footage_to_image_homography(GEOM_1080, pos, att, p)
        fpx = np.array([GEOM_1080.ned_to_px(n, e) for n, e in ground[:, :2]])
        q = np.column_stack([fpx, np.ones(len(fpx))]) @ hf.T
        worst = max(worst, float(np.max(np.abs(q[:, :2] / q[:, 2:] - ref))))
    assert worst < 0.5
    assert worst < 1e-6  # it is the same geometry; anything larger is a bug


def test_rendered_points_land_where_the_pinhole_model_says() -> None:
    """End to end: blobs in the footage at known ground points are found in the rendered VAC image < 0.5 px."""
    rng = np.random.default_rng(3)
    p = CameraParams()
    grid = [(n, e) for n in np.linspace(-30, 30, 7) for e in np.linspace(-50, 50, 9)]
    grid = [(n + rng.uniform(-0.3, 0.3), e + rng.uniform(-0.3, 0.3)) for n, e in grid]
    footage = blob_footage(GEOM_1080, grid, sigma_px=4.0)
    renderer = Renderer(p, GEOM_1080)
    pyramid = LazyPyramid(footage)
    pts = np.array([[n, e, 0.0] for n, e in grid])
    checked, worst, levels = 0, 0.0, set()
    for _ in range(8):
        att = (rng.uniform(-0.25, 0.25), rng.uniform(-0.25, 0.25), rng.uniform(-math.pi, math.pi))
        pos = (rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-90, -35))
        res = renderer.render(pyramid, pos, att)
        levels.update({res.pyramid_level, res.pyramid_level + (res.lod_blend > 0.0)})  # levels read
        uv = project_ned(pts, pos, att, p)
        for q in uv:
            if np.all(np.isfinite(q)) and 15 <= q[0] <= 624 and 15 <= q[1] <= 464:
                worst = max(worst, float(np.max(np.abs(centroid(res.image_bgr, q, 9) - q))))
                checked += 1
    assert checked > 100 and levels == {0, 1}  # both the full-resolution frame and a pyramid level
    assert worst < 0.5


# --- the view at the recording pose is the footage -----------------------------------------------------------------
def _recording_pose_checks(img: np.ndarray, rec_alt_m: float, hfov_deg: float) -> None:
    h, w = img.shape[:2]
    geom = FootageGeometry.from_fov(w, h, rec_alt_m, hfov_deg)
    pose = ((0.0, 0.0, -rec_alt_m), (0.0, 0.0, 0.0))
    full = Renderer(CameraParams(width_px=w, height_px=h, hfov_deg=hfov_deg), geom).render(img, *pose)
    assert full.coverage == pytest.approx(1.0)
    assert np.allclose(full.homography / full.homography[2, 2], np.eye(3), atol=1e-9)
    assert psnr(full.image_bgr, img) >= 35.0
    pyramid = LazyPyramid(img)
    for f in (2, 4, 3):  # downscaled VACs against the area-averaged footage
        p = CameraParams(width_px=w // f, height_px=h // f, hfov_deg=hfov_deg)
        # w // f may not divide exactly: keep the same ground width by adjusting the FoV
        if w % f:
            continue
        res = Renderer(p, geom).render(pyramid, *pose)
        ref = cv2.resize(img, (w // f, h // f), interpolation=cv2.INTER_AREA)
        assert psnr(res.image_bgr, ref) >= 35.0, f


def test_recording_pose_equals_footage_synthetic() -> None:
    _recording_pose_checks(texture(768, 1024, seed=4), rec_alt_m=80.0, hfov_deg=70.0)


@pytest.mark.footage
@pytest.mark.skipif(not SONGDO.exists(), reason=f"shared footage absent: {SONGDO}")
def test_recording_pose_equals_footage_songdo() -> None:
    img = cv2.imread(str(SONGDO))
    assert img is not None and img.shape == (2160, 3840, 3)
    _recording_pose_checks(img, rec_alt_m=100.0, hfov_deg=82.1)


# --- tilt, gimbal, yaw --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("roll_deg", "pitch_deg", "expected_ne"),
    [
        (0.0, 10.0, lambda z: (z * math.tan(10 * DEG), 0.0)),  # nose up: the belly camera looks ahead
        (0.0, -15.0, lambda z: (-z * math.tan(15 * DEG), 0.0)),  # nose down: it looks at the ground behind
        (12.0, 0.0, lambda z: (0.0, -z * math.tan(12 * DEG))),  # right wing down: it looks left (west)
    ],
)
def test_tilt_shifts_view_by_z_tan_theta(roll_deg: float, pitch_deg: float, expected_ne) -> None:
    z = 40.0
    p = CameraParams()
    att = (roll_deg * DEG, pitch_deg * DEG, 0.0)
    centre = pixel_to_ground([[319.5, 239.5]], (0.0, 0.0, -z), att, p)[0]
    n_exp, e_exp = expected_ne(z)
    assert centre[:2] == pytest.approx([n_exp, e_exp], abs=1e-9)
    # and in the rendered image: a marker at that ground point sits at the image centre
    footage = blob_footage(GEOM_1080, [(n_exp, e_exp)], sigma_px=4.0)
    res = Renderer(p, GEOM_1080).render(footage, (0.0, 0.0, -z), att)
    c = centroid(res.image_bgr, np.array([319.5, 239.5]), 12)
    assert np.max(np.abs(c - [319.5, 239.5])) < 0.5


def test_gimbal_ignores_roll_and_pitch_but_follows_yaw() -> None:
    footage = texture(1080, 1920, seed=5)
    pos = (3.0, -2.0, -60.0)
    gimbal = Renderer(CameraParams(mount=Mount.GIMBAL), GEOM_1080)
    fixed = Renderer(CameraParams(mount=Mount.FIXED), GEOM_1080)
    pyr = LazyPyramid(footage)
    level = fixed.render(pyr, pos, (0.0, 0.0, 0.7)).image_bgr
    tilted_gimbal = gimbal.render(pyr, pos, (0.3, -0.25, 0.7)).image_bgr
    tilted_fixed = fixed.render(pyr, pos, (0.3, -0.25, 0.7)).image_bgr
    assert np.array_equal(tilted_gimbal, level)
    assert psnr(tilted_fixed, level) < 20.0  # the rigid mount does tilt
    assert psnr(gimbal.render(pyr, pos, (0.3, -0.25, 0.0)).image_bgr, level) < 20.0  # yaw still turns it


def test_yaw_rotates_view_counter_clockwise() -> None:
    """Positive yaw (clockwise seen from above) makes the world turn counter-clockwise in the image."""
    z, d = 50.0, 12.0
    p = CameraParams(width_px=480, height_px=480, hfov_deg=70.0)
    f = camera_intrinsics(p)[0, 0]
    c = 239.5
    # a feature north of the vehicle: up at yaw 0, left at yaw +90 (nose east: north is on the left), right at -90
    for yaw_deg, expected in (
        (0.0, (c, c - f * d / z)),
        (90.0, (c - f * d / z, c)),
        (-90.0, (c + f * d / z, c)),
    ):
        uv = project_ned([[d, 0.0, 0.0]], (0.0, 0.0, -z), (0.0, 0.0, yaw_deg * DEG), p)[0]
        assert uv == pytest.approx(expected, abs=1e-9)
    # whole image: the view at yaw psi is the yaw-0 view rotated by psi counter-clockwise about the centre
    footage = u8(cv2.GaussianBlur(texture(1080, 1920, seed=6), (0, 0), 3.0))
    r = Renderer(p, GEOM_1080)
    base = r.render(footage, (0.0, 0.0, -z), (0.0, 0.0, 0.0)).image_bgr
    yy, xx = np.mgrid[0:480, 0:480]
    inside = (xx - c) ** 2 + (yy - c) ** 2 < 200**2
    for yaw_deg in (30.0, -50.0):
        view = r.render(footage, (0.0, 0.0, -z), (0.0, 0.0, yaw_deg * DEG)).image_bgr
        rot = cv2.warpAffine(base, cv2.getRotationMatrix2D((c, c), yaw_deg, 1.0), (480, 480))  # +angle: CCW
        wrong = cv2.warpAffine(base, cv2.getRotationMatrix2D((c, c), -yaw_deg, 1.0), (480, 480))
        assert psnr(view[inside], rot[inside]) > 35.0
        assert psnr(view[inside], wrong[inside]) < 25.0


# --- anti-aliasing --------------------------------------------------------------------------------------------------
def test_antialiasing_beats_plain_warp_at_altitude() -> None:
    footage = texture(1080, 1920, seed=7)
    small = CameraParams(
        width_px=160, height_px=120
    )  # a small VAC: high footprint scale with the view inside
    pos, att = (5.0, -8.0, -55.0), (0.05, -0.04, 0.15)  # ~6.6 footage px per VAC px
    ours = Renderer(small, GEOM_1080).render(LazyPyramid(footage), pos, att)
    plain = Renderer(dataclasses.replace(small, antialias=False), GEOM_1080).render(footage, pos, att)
    assert ours.pyramid_level >= 2 and plain.pyramid_level == 0
    assert ours.footage_px_per_vac_px > 5.0
    assert ours.coverage == pytest.approx(1.0)
    ref = supersampled_reference(footage, GEOM_1080, small, pos, att)
    p_ours, p_plain = psnr(ours.image_bgr, ref), psnr(plain.image_bgr, ref)
    assert p_ours >= p_plain + 6.0, (p_ours, p_plain)
    assert p_ours >= 30.0


@pytest.mark.footage
@pytest.mark.skipif(not SONGDO.exists(), reason=f"shared footage absent: {SONGDO}")
def test_antialiasing_real_footage() -> None:
    img = u8(cv2.imread(str(SONGDO)))
    geom = FootageGeometry.from_fov(3840, 2160, 100.0, 82.1)
    small = CameraParams(width_px=320, height_px=180)
    pos, att = (0.0, 0.0, -70.0), (0.0, 0.0, 0.1)  # ~8.4 footage px per VAC px
    ours = Renderer(small, geom).render(LazyPyramid(img), pos, att)
    plain = Renderer(dataclasses.replace(small, antialias=False), geom).render(img, pos, att)
    # trilinear: lod = log2(8.4) - 0.5 = 2.57, levels 2 and 3 blended
    assert ours.coverage == pytest.approx(1.0) and ours.pyramid_level == 2 and ours.lod_blend > 0.5
    ref = supersampled_reference(img, geom, small, pos, att)
    assert psnr(ours.image_bgr, ref) >= psnr(plain.image_bgr, ref) + 3.0


def test_lazy_pyramid_builds_only_what_is_needed() -> None:
    img = texture(1080, 1920, seed=8)
    pyr = LazyPyramid(img)
    assert pyr.built_levels == 1 and pyr.max_level == 11
    Renderer(CameraParams(), GEOM_1080).render(pyr, (0.0, 0.0, -30.0), (0.0, 0.0, 0.0))  # zoomed in: level 0
    assert pyr.built_levels == 1
    res = Renderer(CameraParams(), GEOM_1080).render(pyr, (0.0, 0.0, -250.0), (0.0, 0.0, 0.0))
    assert res.pyramid_level == 2 and pyr.built_levels == 4  # levels 2 and 3 blended (trilinear)
    full = build_pyramid(img, 4)
    assert [a.shape for a in full] == [
        (1080, 1920, 3),
        (540, 960, 3),
        (270, 480, 3),
        (135, 240, 3),
        (68, 120, 3),
    ]
    for i in range(3):
        assert np.array_equal(full[i], pyr.level(i))
    from_list = Renderer(CameraParams(), GEOM_1080).render(full, (0.0, 0.0, -250.0), (0.0, 0.0, 0.0))
    assert np.array_equal(from_list.image_bgr, res.image_bgr)
    with pytest.raises(ValueError):
        LazyPyramid(np.zeros((0, 4, 3), np.uint8))
    with pytest.raises(ValueError):
        build_pyramid(img.astype(np.float32), 2)  # type: ignore[arg-type]


def test_lower_resolution_frame_renders_the_same_view() -> None:
    """A frame decoded at half resolution (e.g. an ingest cache) maps onto the same geometry."""
    img = u8(cv2.GaussianBlur(texture(1080, 1920, seed=9), (0, 0), 2.0))
    half = u8(cv2.resize(img, (960, 540), interpolation=cv2.INTER_AREA))
    r = Renderer(CameraParams(), GEOM_1080)
    pose = ((4.0, 7.0, -90.0), (0.1, 0.05, 0.3))
    assert psnr(r.render(half, *pose).image_bgr, r.render(img, *pose).image_bgr) > 35.0
    with pytest.raises(ValueError, match="aspect"):
        r.render(np.zeros((540, 540, 3), np.uint8), *pose)


# --- outside the footage, horizon, footprint -----------------------------------------------------------------------
def test_coverage_and_fill_outside_footage() -> None:
    footage = texture(1080, 1920, seed=10)
    r = Renderer(CameraParams(), GEOM_1080)
    fill = np.array(DEFAULT_FILL_BGR, np.uint8)
    east_edge = GEOM_1080.ground_width_m / 2
    for pos, att in (
        ((0.0, east_edge, -40.0), (0.0, 0.0, 0.0)),
        ((-20.0, east_edge - 10, -60.0), (0.2, -0.1, 0.9)),
    ):
        res = r.render(footage, pos, att)
        is_fill = np.all(res.image_bgr == fill, axis=2).mean()
        assert 0.2 < res.coverage < 0.8
        assert abs((1.0 - res.coverage) - is_fill) < 0.01
    inside = r.render(footage, (0.0, 0.0, -40.0), (0.0, 0.0, 0.0))
    assert inside.coverage == 1.0 and not np.any(np.all(inside.image_bgr == fill, axis=2))
    far = r.render(footage, (0.0, 5000.0, -40.0), (0.0, 0.0, 0.0))
    assert far.coverage == 0.0 and np.all(far.image_bgr == fill)
    black = Renderer(CameraParams(fill_bgr=(0, 0, 0)), GEOM_1080).render(
        footage, (0.0, 5000.0, -40.0), (0, 0, 0)
    )
    assert not black.image_bgr.any()


def test_coverage_shortcut_equals_the_clipped_polygon() -> None:
    """The renderer's one-product shortcut (every image corner inside the footage, in front of the camera) gives
    exactly the coverage the half-plane clipping gives, and only where nothing is behind the camera to paint."""
    from viva_sitl.camera.projection import clip_convex_polygon, image_corners_px, polygon_area

    rng = np.random.default_rng(3)
    shortcuts = 0
    for size in ((640, 480), (33, 17)):
        p = CameraParams(width_px=size[0], height_px=size[1])
        r = Renderer(p, GEOM_1080)
        for _ in range(1500):
            pos = (
                rng.uniform(-120, 120),
                rng.uniform(-200, 200),
                -float(rng.choice([0.01, 5.0, 40.0, 300.0])),
            )
            att = rng.uniform(-1.3, 1.3, 3) * float(rng.choice([0.0, 0.05, 1.0]))
            _, m = r.view_maps(pos, att, 1920, 1080)
            planes = r._halfplanes(m, 1920, 1080)
            clipped = clip_convex_polygon(image_corners_px(p), planes)
            assert r.coverage(m, 1920, 1080) == min(1.0, polygon_area(clipped) / (size[0] * size[1]))
            if r._sees_only_footage(planes):
                shortcuts += 1
                assert polygon_area(clip_convex_polygon(image_corners_px(p), [-m[2]])) == 0.0
    assert shortcuts > 100  # the shortcut was exercised, not only the clipping


def test_four_channel_warp_equals_the_three_channel_warp(monkeypatch: pytest.MonkeyPatch) -> None:
    """The renderer warps a BGRA copy of the region it reads (faster in OpenCV); the image is bit-identical to
    the 3-channel warp, over and off the footage, tilted, trilinear (two levels) or not."""
    import viva_sitl.camera.renderer as renderer_mod

    footage = texture(1080, 1920, seed=12)
    rng = np.random.default_rng(4)
    poses = [
        ((rng.uniform(-60, 60), rng.uniform(-120, 120), -rng.uniform(8.0, 400.0)), rng.uniform(-0.4, 0.4, 3))
        for _ in range(40)
    ] + [
        ((0.0, GEOM_1080.ground_width_m / 2, -40.0), (0.2, -0.1, 0.9)),
        ((-20.0, 0.0, -15.0), (0.0, 1.2, 0.0)),
    ]
    used = []
    for params in (CameraParams(), CameraParams(width_px=160, height_px=120, trilinear=False)):
        fast, plain = Renderer(params, GEOM_1080), Renderer(params, GEOM_1080)
        pyr = LazyPyramid(footage)
        for pos, att in poses:
            monkeypatch.setattr(renderer_mod, "BGRA_MAX_READ_VIEWS", 4)
            got = fast.render(pyr, pos, att)
            used.append(bool(fast._bgra))
            fast._bgra.clear()
            monkeypatch.setattr(renderer_mod, "BGRA_MAX_READ_VIEWS", -1)  # never: the 3-channel warp
            want = plain.render(pyr, pos, att)
            assert plain._bgra == {}
            assert np.array_equal(got.image_bgr, want.image_bgr), (pos, att)
            assert got.coverage == want.coverage and got.lod_blend == want.lod_blend
            monkeypatch.setattr(renderer_mod, "BGRA_MAX_READ_VIEWS", 4)
            rgb = fast.render(pyr, pos, att, rgb=True, out=np.empty_like(want.image_bgr)).image_bgr
            assert np.array_equal(rgb, want.image_bgr[:, :, ::-1])  # RGB order, converted once
    assert sum(used) > 40  # most poses took the 4-channel warp
    # a view flying across the frame: the BGRA buffer is replaced before its written pages exceed the bound
    r = Renderer(CameraParams(width_px=160, height_px=120), GEOM_1080)
    pyr = LazyPyramid(footage)
    for north in np.linspace(-60.0, 60.0, 40):
        r.render(pyr, (north, 2.0 * north, -30.0), (0.0, 0.0, 0.3))
        for _, (x0, y0, x1, y1) in r._bgra.values():
            assert 0 < (x1 - x0) * (y1 - y0) <= renderer_mod.BGRA_RESET_VIEWS * 160 * 120


def test_rays_above_horizon_are_filled_not_wrapped() -> None:
    footage = texture(1080, 1920, seed=11)
    p = CameraParams()
    # nose up 70 deg: the top of the image sees the sky
    pos, att = (-20.0, 0.0, -15.0), (0.0, 70.0 * DEG, 0.0)
    res = Renderer(p, GEOM_1080).render(footage, pos, att)
    uu, vv = np.meshgrid(np.arange(640.0), np.arange(480.0))
    ground = pixel_to_ground(np.column_stack([uu.ravel(), vv.ravel()]), pos, att, p)
    sky = ~np.isfinite(ground[:, 0]).reshape(480, 640)
    assert 0.1 < sky.mean() < 0.9
    fill = np.array(DEFAULT_FILL_BGR, np.uint8)
    assert np.all(res.image_bgr[sky] == fill)
    assert res.coverage < 1.0 - sky.mean() + 1e-3
    assert ground_footprint(pos, att, p) is None


def test_ground_footprint_nadir() -> None:
    p = CameraParams()
    z = 30.0
    fp = ground_footprint((1.0, 2.0, -z), (0.0, 0.0, 0.0), p)
    assert fp is not None and fp.shape == (4, 3)
    hw = z * math.tan(p.hfov_deg * DEG / 2)
    hh = z * math.tan(p.vfov_effective_deg * DEG / 2)
    # top-left of the image = ahead (north) and left (west) at yaw 0
    expected = [(1 + hh, 2 - hw), (1 + hh, 2 + hw), (1 - hh, 2 + hw), (1 - hh, 2 - hw)]
    assert fp[:, :2] == pytest.approx(np.array(expected), abs=1e-9)
    assert np.all(fp[:, 2] == 0.0)
    # yaw 90 (nose east): the top-left corner is north-east
    fp90 = ground_footprint((0.0, 0.0, -z), (0.0, 0.0, math.pi / 2), p)
    assert fp90 is not None and fp90[0, 0] > 0 and fp90[0, 1] > 0


# --- effects ---------------------------------------------------------------------------------------------------------
def test_sensor_noise_is_seeded_and_has_the_configured_std() -> None:
    footage = np.full((1080, 1920, 3), 128, np.uint8)
    clean = Renderer(CameraParams(), GEOM_1080).render(footage, (0, 0, -50.0), (0, 0, 0)).image_bgr
    noisy = Renderer(CameraParams(noise_std=4.0), GEOM_1080)
    a = noisy.render(footage, (0, 0, -50.0), (0, 0, 0), rng=np.random.default_rng(42)).image_bgr
    b = noisy.render(footage, (0, 0, -50.0), (0, 0, 0), rng=np.random.default_rng(42)).image_bgr
    c = noisy.render(footage, (0, 0, -50.0), (0, 0, 0), rng=np.random.default_rng(43)).image_bgr
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert np.std(a.astype(float) - clean) == pytest.approx(4.0, rel=0.05)
    with pytest.raises(ValueError, match="Generator"):
        noisy.render(footage, (0, 0, -50.0), (0, 0, 0))


def test_motion_blur_along_projected_velocity() -> None:
    # stripes that vary along footage u (east) only: at yaw 0 they vary along image x only
    u = np.arange(1920, dtype=np.float64)
    row = 128 + 100 * np.sin(2 * np.pi * u / 7.2)  # period ~ 8 VAC px at 30 m
    footage = np.repeat(np.repeat(row[None, :, None], 1080, axis=0), 3, axis=2).astype(np.uint8)
    pose = ((0.0, 0.0, -30.0), (0.0, 0.0, 0.0))
    sharp = Renderer(CameraParams(), GEOM_1080).render(footage, *pose).image_bgr
    blur = Renderer(CameraParams(motion_blur=True, exposure_s=0.02), GEOM_1080)
    assert np.array_equal(blur.render(footage, *pose).image_bgr, sharp)  # no velocity, no blur
    assert np.array_equal(blur.render(footage, *pose, vel_ned_m_s=(0.0, 0.0, 0.0)).image_bgr, sharp)
    # 30 m/s for 20 ms at 30 m: a streak of f * 0.6 / 30 ~ 7.3 px, about one stripe period
    north = blur.render(footage, *pose, vel_ned_m_s=(30.0, 0.0, 0.0)).image_bgr  # streak along image y
    east = blur.render(footage, *pose, vel_ned_m_s=(0.0, 30.0, 0.0)).image_bgr  # streak along image x
    assert psnr(north, sharp) > 45.0  # blur along the stripes changes nothing
    assert east.astype(float).std() < 0.3 * sharp.astype(float).std()  # blur across them washes them out
    slow = blur.render(footage, *pose, vel_ned_m_s=(0.0, 3.0, 0.0)).image_bgr  # 0.7 px: barely blurred
    assert 0.8 * sharp.astype(float).std() < slow.astype(float).std() < sharp.astype(float).std()


def test_radial_distortion_matches_opencv_model() -> None:
    p = CameraParams(k1=-0.15, k2=0.02)
    ground = [(n, e) for n in np.linspace(-12, 12, 5) for e in np.linspace(-18, 18, 7)]
    footage = blob_footage(GEOM_1080, ground, sigma_px=4.0)
    pos, att = (0.0, 0.0, -22.0), (0.05, -0.04, 0.2)
    res = Renderer(p, GEOM_1080).render(footage, pos, att)
    r_nc = cam_rot_ned(p, att)
    c = np.array(pos)
    pts = np.array([[n, e, 0.0] for n, e in ground])
    ref = cv2.projectPoints(
        pts.reshape(-1, 1, 3), cv2.Rodrigues(r_nc.T)[0], -r_nc.T @ c, camera_intrinsics(p),
        np.array([p.k1, p.k2, 0.0, 0.0]),
    )[0].reshape(-1, 2)  # fmt: skip
    ideal = project_ned(pts, pos, att, p)
    moved = 0
    for q, qi in zip(ref, ideal, strict=True):
        if 15 <= q[0] <= 624 and 15 <= q[1] <= 464:
            assert np.max(np.abs(centroid(res.image_bgr, q, 9) - q)) < 0.5
            moved += np.hypot(*(q - qi)) > 3.0
    assert moved >= 5  # the distortion really moved points (barrel: toward the centre)
    assert 0.9 < res.coverage <= 1.0


# --- API edges --------------------------------------------------------------------------------------------------------
def test_bad_pose_and_inputs_raise_value_error() -> None:
    footage = texture(108, 192, seed=13)
    geom = FootageGeometry.from_fov(192, 108, 100.0, 82.1)
    r = Renderer(CameraParams(width_px=64, height_px=48), geom)
    for pos, att in (
        ((0.0, math.nan, -10.0), (0.0, 0.0, 0.0)),
        ((0.0, 0.0, -10.0), (0.0, math.inf, 0.0)),
        ((0.0, 0.0), (0.0, 0.0, 0.0)),
        ((0.0, 0.0, -10.0), (0.0, 0.0)),
    ):
        with pytest.raises(ValueError):
            r.render(footage, pos, att)
        with pytest.raises(ValueError):
            project_ned([[0.0, 0.0, 0.0]], pos, att, r.params)
        with pytest.raises(ValueError):
            ground_to_image_homography(pos, att, r.params)
    with pytest.raises(ValueError):
        r.render(footage, (0.0, 0.0, -10.0), (0.0, 0.0, 0.0), vel_ned_m_s=(math.nan, 0.0, 0.0))
    with pytest.raises(ValueError):
        r.render([], (0.0, 0.0, -10.0), (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="uint8"):
        r.render(footage.astype(np.float32), (0.0, 0.0, -10.0), (0.0, 0.0, 0.0))  # type: ignore[arg-type]
    # a vehicle resting on (or numerically below) the ground still renders: the camera is kept just above it
    on_ground = r.render(footage, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert on_ground.coverage == 1.0 and on_ground.image_bgr.shape == (48, 64, 3)


def test_render_view_helper() -> None:
    footage = texture(1080, 1920, seed=14)
    pose = ((2.0, -3.0, -70.0), (0.02, 0.03, -0.4))
    img = render_view(footage, GEOM_1080, CameraParams(), *pose)
    ref = Renderer(CameraParams(), GEOM_1080).render(LazyPyramid(footage), *pose).image_bgr
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    assert np.array_equal(img, ref)


def test_renderer_view_cache_matches_fresh_renderers() -> None:
    """The renderer keeps the last pose's maps (the simulator plans its region with them just before rendering):
    a long-lived renderer over repeated poses, a changed mount and a lower-resolution frame renders exactly what a
    fresh renderer does, and its results own their homography."""
    footage = texture(1080, 1920, seed=12)
    half = u8(cv2.resize(footage, (960, 540), interpolation=cv2.INTER_AREA))
    p = CameraParams()
    tilted = dataclasses.replace(p, mount_pitch_deg=20.0)
    live = Renderer(p, GEOM_1080)
    poses = [
        ((0.0, 0.0, -40.0), (0.0, 0.0, 0.0), p, footage),
        ((0.0, 0.0, -40.0), (0.0, 0.0, 0.0), p, footage),  # the same pose again: cached maps
        ((0.0, 0.0, -40.0), (0.0, 0.0, 0.0), p, half),  # same pose, another frame size
        ((3.0, -2.0, -35.0), (0.05, -0.02, 0.4), p, footage),
        ((3.0, -2.0, -35.0), (0.05, -0.02, 0.4), tilted, footage),  # new params object, same pose
        ((3.0, -2.0, -35.0), (0.05, -0.02, 0.4), p, footage),
    ]
    for pos, att, params, img in poses:
        live.params = params
        got = live.render(LazyPyramid(img), pos, att)
        want = Renderer(params, GEOM_1080).render(LazyPyramid(img), pos, att)
        assert np.array_equal(got.image_bgr, want.image_bgr)
        assert got.coverage == want.coverage and got.pyramid_level == want.pyramid_level
        assert np.array_equal(got.homography, want.homography) and got.homography.flags.writeable
        got.homography[:] = 0.0  # the caller's copy: the renderer's cached map is untouched
    again = live.render(LazyPyramid(footage), *poses[-1][:2])
    assert np.array_equal(again.image_bgr, Renderer(p, GEOM_1080).render(footage, *poses[-1][:2]).image_bgr)


def test_clip_convex_polygon_unclipped_and_clipped() -> None:
    from viva_sitl.camera.projection import clip_convex_polygon

    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    same = clip_convex_polygon(square, [np.array([1.0, 0.0, 1.0])])  # x >= -1: nothing clipped
    assert np.array_equal(same, square) and same is not square
    half = clip_convex_polygon(square, [np.array([-1.0, 0.0, 1.0])])  # x <= 1
    assert np.allclose(half, [[0.0, 0.0], [1.0, 0.0], [1.0, 2.0], [0.0, 2.0]])
    assert clip_convex_polygon(square, [np.array([1.0, 0.0, -5.0])]).shape == (0, 2)
