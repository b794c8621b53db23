"""The companion-side ground homography from FrameMeta equals the SITL's own projection (fixed and gimbal mounts)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from viva_sitl.camera import CameraParams, Mount, ground_to_image_homography, pixel_to_ground
from viva_sitl.dynamics import EavState
from viva_sitl.perception import PerceptionError
from viva_sitl.perception.detect import Detection, Detector
from viva_sitl.perception.geometry import ground_homography_from_meta, image_to_ground
from viva_sitl.sim import Simulator


@pytest.mark.parametrize(
    "cam",
    [
        CameraParams(),
        CameraParams(mount=Mount.GIMBAL, mount_pitch_deg=-20.0, cam_pos_body_m=(0.1, 0.0, 0.05)),
    ],
)
def test_meta_homography_matches_the_render_pose(cam: CameraParams) -> None:
    pos, att = np.array([4.0, -2.0, -22.0]), np.array([0.08, -0.12, 0.9])
    with Simulator(footage="synthetic", camera=cam) as sim:
        s = EavState.at_rest(pos, yaw_rad=att[2], roll_rad=att[0], pitch_rad=att[1])
        meta = sim.render(dataclasses.replace(s, time_s=1.0), wall_time_s=0.0).meta
    h_meta = ground_homography_from_meta(meta)
    h_sim = ground_to_image_homography(pos, att, cam)
    np.testing.assert_allclose(h_meta / h_meta[2, 2], h_sim / h_sim[2, 2], rtol=1e-9, atol=1e-9)
    # the dict the frame-and-pose socket sends (JSON) works the same
    h_json = ground_homography_from_meta(json.loads(json.dumps(meta.to_dict())))
    np.testing.assert_allclose(h_json, h_meta)
    px = np.array([[10.0, 20.0], [320.0, 240.0], [600.0, 450.0]])
    np.testing.assert_allclose(
        image_to_ground(h_meta, px), pixel_to_ground(px, pos, att, cam)[:, :2], atol=1e-6
    )
    d = Detection(0, "person", 0.8, (300.0, 200.0, 310.0, 212.0))
    np.testing.assert_allclose(Detector.on_ground([d], meta=meta), Detector.on_ground([d], pos, att, cam))
    with pytest.raises(PerceptionError, match="needs the frame's pose"):
        Detector.on_ground([d])
