"""The headless Python API: reset with a seed and a pose, step with a command, get the state and the VAC frame.

    sim = Simulator(SimConfig(), footage="synthetic")
    state = sim.reset(seed=0, pos_ned_m=(0, 0, -50), yaw_rad=0.0)
    state = sim.step(EavCommand(roll_rad=0, pitch_rad=0, yaw_rad=0, thrust_n=sim.params.hover_thrust_n))
    frame = sim.render()          # RenderedFrame: image_bgr + FrameMeta (pose, intrinsics, footage index)

Free-running: nothing here reads a clock. `render(state)` may be called from one worker thread while another
thread steps (states are frozen); the footage decoder and pyramid cache belong to the rendering thread.

Speed (bench/results_core.md): over a 4:2:0 video, `render` converts to BGR only the part of the footage frame the
VAC will read (its footprint's bounding box at the chosen pyramid level, plus a margin) instead of the whole frame,
and builds the lower pyramid level from that part only; the image is bit-identical to rendering from the fully
converted frame (tests/test_sim_speed_paths.py). `prefetch=True` also decodes the next footage frame on a
background thread while the caller steps and renders. `footage_frame` still returns the whole converted frame.
Over a tile cache (`viva_sitl.footage.tiles.TileSource`, from `viva-sitl footage ingest --tiles`) the same plan
decodes only the tiles under the footprint at the level(s) the renderer reads (two with trilinear blending).
"""

from __future__ import annotations

import dataclasses
import math
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.camera import (
    CameraParams,
    LazyPyramid,
    Renderer,
    RenderResult,
    camera_extrinsics,
    camera_intrinsics,
)
from viva_sitl.camera.projection import cam_rot_ned, camera_center_ned
from viva_sitl.camera.pyramid import RegionPyramid
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavCommand, EavParams, EavState, floats3, step
from viva_sitl.footage import FootageSource, open_footage
from viva_sitl.footage.source import RegionRead
from viva_sitl.frame import FrameMeta, RenderedFrame
from viva_sitl.geo import GeoOrigin

# Source pixels (at the rendered level) added around the footprint's bounding box: bilinear reads the next pixel,
# and OpenCV rounds warp coordinates to 1/32 px.
REGION_MARGIN_PX = 2
_W_EPS = 1e-9  # as the renderer: homogeneous w at or below this is a ray at or above the horizon


class MagnifiedRenderLike(Protocol):
    """What `Simulator.super_resolution` holds (viva_sitl.perception.MagnifiedRender): kept structural so the core
    never imports the perception extra."""

    def magnified(self, renderer: Renderer, pos_ned_m: np.ndarray, att_rpy_rad: np.ndarray) -> bool: ...

    def render(
        self,
        renderer: Renderer,
        image0_bgr: np.ndarray,
        pos_ned_m: np.ndarray,
        att_rpy_rad: np.ndarray,
        vel_ned_m_s: np.ndarray | None = None,
        rng: np.random.Generator | None = None,
    ) -> RenderResult: ...


class Simulator:
    """One vehicle (the EAV) with its camera (the VAC) over one footage."""

    def __init__(
        self,
        config: SimConfig | None = None,
        footage: str | Path | FootageSource | None = None,
        camera: CameraParams | None = None,
        *,
        region_render: bool = True,
        prefetch: bool = False,
        footage_levels: bool = False,
    ) -> None:
        """`region_render`: convert only the part of each video frame the VAC reads (same image, faster);
        `prefetch`: decode the next footage frame on a background thread (same frames, overlaps decode with the
        caller's work; one extra thread, ended by `close`); `footage_levels` (with `region_render`, over an
        ingest-cache footage that has reduced copies): when the VAC renders from pyramid level >= 1, decode the
        copy of that resolution instead of the full frame (much faster when high up, but NOT the same image: the
        copy is a separately encoded, lossy video; see tests/test_sim_speed_paths.py for the measured PSNR)."""
        self.config = config or SimConfig()
        if isinstance(footage, str | Path) or footage is None:
            self.footage: FootageSource = open_footage(
                footage if footage is not None else self.config.footage,
                altitude_m=self.config.footage_alt_m,
                hfov_deg=self.config.footage_hfov_deg,
                gsd_m_per_px=self.config.footage_gsd_m_per_px,
            )
        else:
            self.footage = footage
        self.camera = camera or self.config.camera
        self.renderer = Renderer(self.camera, self.footage.geometry)
        self.params: EavParams = self.config.physics
        self._pyramid_index = -1
        self._pyramid: LazyPyramid | None = None
        self._pyramid_source: object = None  # the ground-view image `_pyramid` was built from
        self._frame_counter = 0
        # constant per camera: FrameMeta fields computed once per CameraParams (see _camera_fields)
        self._fields_camera: CameraParams | None = None
        self._intrinsics_k: tuple[tuple[float, float, float], ...] = ()
        self._cam_pos_body_m = (0.0, 0.0, 0.0)
        self._region: RegionPyramid | None = None
        self._plan_quad = np.zeros((0, 2))  # the last plan's footprint corners (level-0 px)
        self._footage_levels = footage_levels
        # footage level the last region render decoded (what prefetch decodes next)
        self._source_level_used = 0
        self.region_renders = 0  # statistics: renders served by the region path / by the whole frame
        self.full_renders = 0
        # what the footage can do (its capabilities) picks the render path, never its type
        caps = self.footage.capabilities
        if region_render and caps.region is not RegionRead.NONE and not self.camera.has_distortion:
            w, h = self.footage.frame_size_px
            # BGRA (video crops are converted to it, tiles as they are pasted): the renderer's 4-channel warp reads
            # the region buffers directly
            self._region = RegionPyramid(w, h, channels=4)
        # --- shared-decode hook (viva_sitl.gym): footage time = sim time + footage_offset_s. Copies of a vector
        # env flying over ONE FootageSource at the same footage time read the same decoded frame. ---
        self.footage_offset_s = 0.0
        # super-resolution hook (issue 9): a viva_sitl.perception.MagnifiedRender, or None (default: off)
        self.super_resolution: MagnifiedRenderLike | None = None
        self._prefetcher: ThreadPoolExecutor | None = None
        self._prefetch_job: Future[None] | None = None
        if prefetch and caps.prefetch and self.footage.frame_count > 1:
            self._prefetcher = ThreadPoolExecutor(max_workers=1, thread_name_prefix="viva-sitl-prefetch")
        self.reset(self.config.seed)

    def set_camera(self, camera: CameraParams) -> None:
        """Replace the VAC's parameters (e.g. a gimbal's new mount angles); the next render uses them."""
        if camera == self.camera:
            return
        intrinsics_same = dataclasses.replace(
            camera, mount_roll_deg=0.0, mount_pitch_deg=0.0, mount_yaw_deg=0.0
        ) == dataclasses.replace(self.camera, mount_roll_deg=0.0, mount_pitch_deg=0.0, mount_yaw_deg=0.0)
        if intrinsics_same:
            self.renderer.params = camera  # mount angles are read per render; K and the lens maps stay valid
        else:
            self.renderer = Renderer(camera, self.renderer.geometry)
        self.camera = camera

    # --- geometry ------------------------------------------------------------------
    @property
    def geo(self) -> GeoOrigin:
        """NED origin on the ground (footage centre): the configured home (places any footage), else the footage's
        geo-reference, else PX4 SITL's default home."""
        return self.config.home or self.footage.geometry.geo_origin or GeoOrigin()

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

    # --- the footage clock ---------------------------------------------------------------
    def footage_time_s(self, time_s: float | None = None) -> float:
        """Footage time at sim time `time_s` (default: now): sim time + footage_offset_s, the ONE footage clock
        (an episode's start time in the footage, a vector env copy's slot); FootageSource.frame_index_at maps it
        to a frame (looping, stills)."""
        return float(self.state.time_s if time_s is None else time_s) + self.footage_offset_s

    def footage_index(self, time_s: float | None = None) -> int:
        """The footage frame shown at sim time `time_s` (default: now)."""
        return int(self.footage.frame_index_at(self.footage_time_s(time_s)))

    # --- camera --------------------------------------------------------------------------
    def footage_frame(self, time_s: float) -> tuple[int, LazyPyramid]:
        """The footage frame at footage time t (sim time + footage_offset_s; deterministic, looping) and its cached
        pyramid."""
        index = self.footage.frame_index_at(time_s)
        if index != self._pyramid_index or self._pyramid is None:
            self._pyramid = LazyPyramid(self.footage.frame(index))
            self._pyramid_index = index
            self._pyramid_source = None
        return index, self._pyramid

    def _plan_region(
        self, s: EavState, region: RegionPyramid, exact: bool = True
    ) -> tuple[int, bool, int, int, int, int] | None:
        """(level, blend, x0, y0, x1, y1): the pyramid level the renderer will warp from at `s`, whether it also
        reads level + 1 (trilinear blend), and the level-0 region it will read (bounding box of the VAC's corner
        pixels mapped to the footage, plus REGION_MARGIN_PX at the coarser level read, aligned to 2^level, clipped
        to the frame; empty when the view misses the frame). None when the view is unbounded (horizon in view) or,
        with `exact`, the level(s) cannot be built from a region by exact halvings.

        Repeats the renderer's own homography and level choice (same operations, so the same numbers);
        `render` checks the level it actually used and falls back to the whole frame if they ever disagree.
        """
        cam = self.camera
        w0, h0 = region.width_px, region.height_px
        _, vac_to_src = self.renderer.view_maps(s.pos_ned_m, s.att_rpy_rad, w0, h0)  # kept for its render
        level, blend_w, _ = self.renderer.choose_lod(vac_to_src, region.max_level)
        blend = blend_w > 0.0
        if exact and not (region.exact_level(level) and (not blend or region.exact_level(level + 1))):
            return None
        wv, hv = cam.width_px - 1.0, cam.height_px - 1.0
        corners = np.array([[0.0, 0.0, 1.0], [wv, 0.0, 1.0], [wv, hv, 1.0], [0.0, hv, 1.0]]) @ vac_to_src.T
        # the rest on the 4 corners in plain floats: the same IEEE operations as numpy's elementwise ones, without
        # its per-call cost (~15 small-array calls per frame)
        cs = corners.tolist()
        if any(
            not (w > _W_EPS) or not (math.isfinite(x) and math.isfinite(y) and math.isfinite(w))
            for x, y, w in cs
        ):
            return None  # the footprint is unbounded: the whole frame may be read
        quad = [(x / w, y / w) for x, y, w in cs]
        self._plan_quad = np.array(quad)  # level-0 footprint of the VAC's corner pixels
        # level-0 pixel -> level-L pixel (edges aligned): u_L = (u_0 + 0.5) / 2^L - 0.5
        scale = 1.0 / (1 << level)
        u = [(x + 0.5) * scale - 0.5 for x, _ in quad]
        v = [(y + 0.5) * scale - 0.5 for _, y in quad]
        lw, lh = region.sizes_px[level]
        margin = REGION_MARGIN_PX << int(blend)  # REGION_MARGIN_PX at level + 1 too
        j0 = max(0, min(lw, math.floor(min(u)) - margin))
        j1 = max(0, min(lw, math.floor(max(u)) + 1 + margin))
        i0 = max(0, min(lh, math.floor(min(v)) - margin))
        i1 = max(0, min(lh, math.floor(max(v)) + 1 + margin))
        return level, blend, j0 << level, i0 << level, min(w0, j1 << level), min(h0, i1 << level)

    def _region_pyramid(self, index: int, s: EavState) -> tuple[RegionPyramid, int] | None:
        """The region pyramid filled for rendering footage frame `index` at `s`, and its level; None: use the whole
        frame."""
        region = self._region
        if region is None:
            return None
        if self._pyramid_index == index and self._pyramid is not None:
            return None  # the whole frame is already converted (footage_frame was called): reuse it
        reads = self.footage.capabilities.region
        if reads is RegionRead.TILES:
            return self._tile_region(index, s, region)
        if reads is not RegionRead.CROP:
            return None
        plan = self._plan_region(s, region)
        if plan is None:
            return None
        level, blend, x0, y0, x1, y1 = plan
        src_level = self._source_level(level, region)
        # align to the 2x2 chroma grid of the decoded frame (level src_level) and to 2^level (2^(level+1) to blend)
        a = max(1 << (level + int(blend)), 2 << src_level)
        x0, y0 = x0 // a * a, y0 // a * a
        x1, y1 = min(region.width_px, -(-x1 // a) * a), min(region.height_px, -(-y1 // a) * a)
        key = (index, level, blend, src_level, x0, y0, x1, y1)
        if region.key == key:
            return region, level
        region.clear()
        if x1 > x0 and y1 > y0:
            img = self.footage.frame_region(
                index, x0 >> src_level, y0 >> src_level, x1 >> src_level, y1 >> src_level, level=src_level
            )
            if img is None:  # not a 4:2:0 stream: never try again
                self._region = None
                return None
            # converted to BGRA as it is pasted (a separate BGR -> BGRA pass of the warp's read box, and its
            # buffer, are saved)
            region.fill(level, x0, y0, img, source_level=src_level, next_level=blend)
        region.key = key
        self._source_level_used = src_level
        return region, level

    def _tile_region(
        self, index: int, s: EavState, region: RegionPyramid
    ) -> tuple[RegionPyramid, int] | None:
        """The region pyramid filled from the tile cache: level (and level + 1 to blend) pixels under the plan,
        as BGRA (the alpha is 255; the renderer's 4-channel warp reads it without a conversion of its own)."""
        plan = self._plan_region(s, region, exact=False)
        if plan is None:
            return None
        level, blend, x0, y0, x1, y1 = plan
        key = (index, level, blend, x0, y0, x1, y1)
        if region.key == key:
            return region, level
        region.clear()
        # the blend's second level halved from the first instead of decoded from its own tiles, where each tile
        # costs a decode (not raw) and the halving is exact: at 300 m over 4K that is ~6 jpeg tiles per frame
        halve = blend and self.footage.capabilities.region_decodes and region.exact_level(level + 1)
        margin = float(REGION_MARGIN_PX + 1)
        if x1 > x0 and y1 > y0:
            for lv in (level,) if halve or not blend else (level, level + 1):
                lw, lh = region.sizes_px[lv]
                lx0, ly0 = x0 >> lv, y0 >> lv
                lx1, ly1 = min(lw, -(-x1 >> lv)), min(lh, -(-y1 >> lv))
                if halve:  # an even box, and tiles far enough around the footprint for level + 1's margin
                    lx0, ly0, lx1, ly1 = (
                        lx0 & ~1,
                        ly0 & ~1,
                        min(lw, lx1 + (lx1 & 1)),
                        min(lh, ly1 + (ly1 & 1)),
                    )
                    margin = float(2 * (REGION_MARGIN_PX + 1) + 2)
                if lx1 > lx0 and ly1 > ly0:  # decoded tiles copied straight into the level's buffer
                    out = region.level_buffer(lv, lx0, ly0, lx1, ly1)
                    # only the tiles near the footprint polygon (a yawed view covers ~half its bounding box)
                    quad = (self._plan_quad + 0.5) / (1 << lv) - 0.5
                    self.footage.region(index, lv, lx0, ly0, lx1, ly1, out, quad, margin)
                    region.mark_filled(lv)
                    if halve:
                        region.halve_into_next(lv, lx0, ly0, lx1, ly1)
        region.key = key
        return region, level

    def _source_level(self, level: int, region: RegionPyramid) -> int:
        """The footage level to decode for pyramid level `level`: 0 (the source), or with `footage_levels` the
        deepest ingest-cache copy <= level whose size is that pyramid level's."""
        if not self._footage_levels or level == 0 or not self.footage.capabilities.reduced_copies:
            return 0
        for k in range(min(level, self.footage.level_count - 1), 0, -1):
            if self.footage.level_size_px(k) == region.sizes_px[k]:
                return k
        return 0

    def _prefetch_next(self, index: int) -> None:
        """Start decoding the footage frame after `index` on the prefetch thread (one job at a time)."""
        if self._prefetcher is None or not self.footage.capabilities.prefetch:
            return
        if self._prefetch_job is not None and not self._prefetch_job.done():
            return
        # only_next: a job that runs late (a starved thread), after this loop has moved on, is skipped rather
        # than seeking the shared decoder away from the frames this loop reads next
        self._prefetch_job = self._prefetcher.submit(
            self.footage.prefetch, index + 1, self._source_level_used, True
        )

    def _render_ground_view(
        self, s: EavState, rgb: bool = False, out: NDArray[np.uint8] | None = None
    ) -> tuple[int, RenderResult]:
        """An edgeless procedural ground (capabilities.ground_view: the synthetic field): render from a window drawn
        around the footprint."""
        index = self.footage.frame_index_at(s.time_s + self.footage_offset_s)
        cam = self.camera
        k = camera_intrinsics(cam)
        us = np.linspace(-0.5, cam.width_px - 0.5, 9)
        vs = np.linspace(-0.5, cam.height_px - 0.5, 7)
        border = [(u, vs[0]) for u in us] + [(u, vs[-1]) for u in us] + [(us[0], v) for v in vs]
        border += [(us[-1], v) for v in vs] + [((cam.width_px - 1) / 2.0, (cam.height_px - 1) / 2.0)]
        px = np.column_stack([np.asarray(border), np.ones(len(border))])
        rays = px @ np.linalg.inv(k).T @ cam_rot_ned(cam, s.att_rpy_rad).T
        centre = camera_center_ned(cam, s.pos_ned_m, s.att_rpy_rad)
        ground_px_m = max(-float(centre[2]), 0.01) / max(float(k[0, 0]), float(k[1, 1]))
        image, geometry = self.footage.ground_view(index, centre, rays, ground_px_m)
        if self._pyramid is None or self._pyramid_source is not image:
            self._pyramid, self._pyramid_source, self._pyramid_index = LazyPyramid(image), image, -1
        # the window's geometry: the renderer keeps no other per-frame state
        self.renderer.geometry = geometry
        self.full_renders += 1
        return index, self.renderer.render(
            self._pyramid, s.pos_ned_m, s.att_rpy_rad, s.vel_ned_m_s, self.camera_rng, rgb=rgb, out=out
        )

    def _render_image(
        self, s: EavState, rgb: bool = False, out: NDArray[np.uint8] | None = None
    ) -> tuple[int, RenderResult]:
        """(footage frame index, render result); `rgb`, `out`: the image in RGB order, written into `out` (see
        Renderer.render)."""
        if self.footage.capabilities.ground_view:
            return self._render_ground_view(s, rgb, out)
        # --- super-resolution hook (issue 9): low flight renders from an upscaled crop of the full frame ---
        sr = self.super_resolution
        if sr is not None and sr.magnified(self.renderer, s.pos_ned_m, s.att_rpy_rad):
            index, pyramid = self.footage_frame(s.time_s + self.footage_offset_s)
            self.full_renders += 1
            res = sr.render(
                self.renderer, pyramid.level(0), s.pos_ned_m, s.att_rpy_rad, s.vel_ned_m_s, self.camera_rng
            )
            if rgb or out is not None:
                img = (
                    res.image_bgr
                    if not rgb
                    else np.asarray(cv2.cvtColor(res.image_bgr, cv2.COLOR_BGR2RGB), np.uint8)
                )
                if out is not None:
                    out[...] = img
                res = dataclasses.replace(res, image_bgr=img if out is None else out)
            return index, res
        # --- end of the super-resolution hook ---
        index = self.footage.frame_index_at(s.time_s + self.footage_offset_s)
        planned = self._region_pyramid(index, s)
        if planned is not None:
            region, level = planned
            rng_state = self.camera_rng.bit_generator.state
            result = self.renderer.render(
                region, s.pos_ned_m, s.att_rpy_rad, s.vel_ned_m_s, self.camera_rng, rgb=rgb, out=out
            )
            if result.coverage == 0.0 or result.pyramid_level == level:
                self.region_renders += 1
                return index, result
            self.camera_rng.bit_generator.state = rng_state  # the same noise on the whole-frame render below
        index, pyramid = self.footage_frame(s.time_s + self.footage_offset_s)
        self.full_renders += 1
        return index, self.renderer.render(
            pyramid, s.pos_ned_m, s.att_rpy_rad, s.vel_ned_m_s, self.camera_rng, rgb=rgb, out=out
        )

    def render_rgb(
        self, state: EavState | None = None, out: NDArray[np.uint8] | None = None
    ) -> NDArray[np.uint8]:
        """The VAC view at `state` (default: the current state) as an RGB image only (no FrameMeta): the same
        pixels as `render(...).image_bgr` reversed, one conversion less (for the gym's observations). `out`: an
        (h, w, 3) uint8 array to write it into (a vector env's batch slot), returned."""
        s = self.state if state is None else state
        index, result = self._render_image(s, rgb=True, out=out)
        self._prefetch_next(index)
        self._frame_counter += 1
        return result.image_bgr

    def render(self, state: EavState | None = None, wall_time_s: float | None = None) -> RenderedFrame:
        """Render the VAC view at `state` (default: the current state)."""
        s = self.state if state is None else state
        wall = time.time() if wall_time_s is None else wall_time_s
        index, result = self._render_image(s)
        self._prefetch_next(index)
        lat, lon, alt = self.geo.ned_to_global(*floats3(s.pos_ned_m))
        if self._fields_camera is not self.camera:
            self._intrinsics_k = tuple(floats3(row) for row in camera_intrinsics(self.camera))
            self._cam_pos_body_m = floats3(np.asarray(camera_extrinsics(self.camera)[1]))
            self._fields_camera = self.camera
        meta = FrameMeta(
            frame_counter=self._frame_counter,
            sim_time_s=s.time_s,
            wall_time_s=wall,
            pos_ned_m=floats3(s.pos_ned_m),
            att_rpy_rad=floats3(s.att_rpy_rad),
            vel_ned_m_s=floats3(s.vel_ned_m_s),
            footage_frame_index=index,
            width_px=self.camera.width_px,
            height_px=self.camera.height_px,
            intrinsics_k=self._intrinsics_k,
            cam_rot_body=tuple(floats3(row) for row in result.cam_rot_body),  # gimbal-aware
            cam_pos_body_m=self._cam_pos_body_m,
            coverage=float(result.coverage),
            lat_deg=lat,
            lon_deg=lon,
            alt_amsl_m=alt,
        )
        self._frame_counter += 1
        return RenderedFrame(result.image_bgr, meta)

    def close(self) -> None:
        if self._prefetcher is not None:
            self._prefetcher.shutdown(wait=True, cancel_futures=True)  # joins the prefetch thread
            self._prefetcher = None
        self.footage.close()

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
