"""Labelled VAC datasets: images at seeded random poses with YOLO boxes, risk masks and poses from the world model.

    viva-sitl dataset export --footage synthetic --n 200 --seed 0 -o data/synth
    export_dataset(ExportSpec(footages=("synthetic",), n=200, seed=0), Path("data/synth"))

Per image (split = train | val):
    images/<split>/<stem>.jpg     the VAC frame (what the SITL streams at that pose and footage time)
    labels/<split>/<stem>.txt     YOLO: class cx cy w h (normalised); class ids = viva_sitl.world.ObjectClass values
    masks/<split>/<stem>.png      uint8 risk level per pixel, 1..5; 0 = no ground seen (sky, off the footage)
    poses/<split>/<stem>.json     pose, footage time/frame, K, camera rotation, ground->image homography, coverage
data.yaml (ultralytics reads it as is; it has no `path`, so paths resolve next to the file), and export.json (the
spec, for reproduction).

Labels go through the same geometry as the image: each object's ground rectangle (its size along the footage axes,
or its true heading for the synthetic field's actors) is projected by the ground->image homography of the pose; the
projected quadrilateral is clipped to the image, its axis-aligned bounding box kept if at least `min_visible` of its
area is inside (and it is >= 2 px a side). Masks sample `WorldModel.risk_levels_at` at each pixel's ground point:
the static risk map (nearest cell) raised around the objects present at that time.

Split: `region` (default) cuts the ground at an east coordinate: val poses see only ground east of it, train poses
only ground west of it (their whole footprint), so validation never sees training ground (the cut leaves
`val_fraction` of the footage's east-west extent, or of [-radius, radius] on the unbounded synthetic field, to val); `footage` puts every image
of `val_footage` in val and the others in train.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.camera import CameraParams
from viva_sitl.camera.projection import (
    camera_intrinsics,
    clip_convex_polygon,
    ground_footprint,
    ground_to_image_homography,
    pixel_to_ground,
    polygon_area,
)
from viva_sitl.perception.errors import PerceptionError

F64 = NDArray[np.float64]
SYNTHETIC_RADIUS_M = 60.0  # the synthetic field's people and cars live within this of the origin


@dataclass(frozen=True)
class PoseRanges:
    """Uniform ranges of the random poses. SPEC text: 'alt=15:60,tilt=0:15,yaw=0:360,radius=60' (any subset).

    alt: m above ground; tilt: deg off nadir (random direction: roll/pitch); yaw: deg; radius: m around the origin
    where positions are drawn on an unbounded ground (the synthetic field). On real footage positions are drawn so
    the whole footprint lies on the footage.
    """

    alt_m: tuple[float, float] = (15.0, 60.0)
    tilt_deg: tuple[float, float] = (0.0, 15.0)
    yaw_deg: tuple[float, float] = (0.0, 360.0)
    radius_m: float = SYNTHETIC_RADIUS_M

    @classmethod
    def parse(cls, text: str) -> PoseRanges:
        out = cls()
        keys = {"alt": "alt_m", "tilt": "tilt_deg", "yaw": "yaw_deg"}
        for part in filter(None, (p.strip() for p in text.split(","))):
            key, _, val = part.partition("=")
            key = key.strip().lower()
            try:
                if key == "radius":
                    out = replace(out, radius_m=float(val))
                elif key in keys:
                    lo, sep, hi = val.partition(":")
                    rng = (float(lo), float(hi if sep else lo))
                    out = replace(out, **{keys[key]: rng})  # type: ignore[arg-type]
                else:
                    raise ValueError
            except ValueError:
                raise PerceptionError(
                    f"bad --poses item {part!r}: expected alt=LO:HI, tilt=LO:HI, yaw=LO:HI or radius=R"
                ) from None
        out.check()
        return out

    def check(self) -> None:
        lo, hi = self.alt_m
        if not (math.isfinite(lo) and math.isfinite(hi) and 0.5 <= lo <= hi):
            raise PerceptionError(f"pose alt range must satisfy 0.5 <= lo <= hi, got {self.alt_m}")
        lo, hi = self.tilt_deg
        if not (0.0 <= lo <= hi < 60.0):
            raise PerceptionError(f"pose tilt range must satisfy 0 <= lo <= hi < 60 deg, got {self.tilt_deg}")
        if not all(math.isfinite(v) for v in self.yaw_deg) or self.yaw_deg[0] > self.yaw_deg[1]:
            raise PerceptionError(f"pose yaw range must be LO <= HI, got {self.yaw_deg}")
        if not (math.isfinite(self.radius_m) and self.radius_m > 0.0):
            raise PerceptionError(f"pose radius must be > 0, got {self.radius_m}")


@dataclass(frozen=True)
class ExportSpec:
    footages: tuple[str, ...] = ("synthetic",)
    n: int = 100  # images per footage
    seed: int = 0
    poses: PoseRanges = field(default_factory=PoseRanges)
    split: str = "region"  # region | footage
    val_fraction: float = 0.2  # region split: share of the ground (east side) and of the images for val
    val_footage: str = ""  # footage split: this footage is val
    min_visible: float = 0.5  # drop a box with less of its projected area inside the image
    width_px: int = 640
    height_px: int = 480
    jpeg_quality: int = 95

    def check(self) -> None:
        if not self.footages:
            raise PerceptionError("dataset export needs at least one --footage")
        if self.n < 1:
            raise PerceptionError(f"--n must be >= 1, got {self.n}")
        if self.split not in ("region", "footage"):
            raise PerceptionError(f"--split must be region or footage, got {self.split!r}")
        if self.split == "region" and not 0.0 < self.val_fraction < 1.0:
            raise PerceptionError(f"--val must be in (0, 1), got {self.val_fraction}")
        if self.split == "footage" and self.val_footage not in self.footages:
            raise PerceptionError(
                f"--split footage needs --val-footage naming one of the footages {list(self.footages)}"
            )
        if self.split == "footage" and len(self.footages) < 2:
            raise PerceptionError("--split footage needs at least two footages (one for train, one for val)")
        if not 0.0 < self.min_visible <= 1.0:
            raise PerceptionError(f"--min-visible must be in (0, 1], got {self.min_visible}")
        self.poses.check()


@dataclass(frozen=True)
class Pose:
    pos_ned_m: tuple[float, float, float]
    att_rpy_rad: tuple[float, float, float]
    time_s: float


@dataclass(frozen=True)
class Box:
    object_class: int
    x0: float
    y0: float
    x1: float
    y1: float
    visible: float  # fraction of the projected area inside the image

    def yolo_line(self, width_px: int, height_px: int) -> str:
        cx, cy = (self.x0 + self.x1) / 2.0 / width_px, (self.y0 + self.y1) / 2.0 / height_px
        w, h = (self.x1 - self.x0) / width_px, (self.y1 - self.y0) / height_px
        return f"{self.object_class} {cx:.6f} {cy:.6f} {w:.6f} {h:.6f}"


def ground_rectangles(world: object, t_s: float) -> list[tuple[int, F64]]:
    """(class, (k, 2) convex ground outline north/east) of every object present at t.

    Footage tracks are boxes along the footage axes; the synthetic field's actors use their true shape (people:
    discs; cars: rectangles along their heading).
    """
    from viva_sitl.footage.synthetic_actors import DEFAULT_ACTORS, actor_heading_rad
    from viva_sitl.world import WorldModel

    assert isinstance(world, WorldModel)
    objs = world.tracks.objects_at(t_s)
    g = world.geometry
    pg = g.px_to_ground
    u_dir = pg[:2, 0] / np.hypot(*pg[:2, 0])  # ground direction of footage +u (north, east)
    v_dir = pg[:2, 1] / np.hypot(*pg[:2, 1])
    actors = {a.name: a for a in DEFAULT_ACTORS}
    out: list[tuple[int, F64]] = []
    for k in range(len(objs)):
        info = world.tracks.tracks[int(objs.track[k])]
        c = objs.ne_m[k]
        a_dir, b_dir = u_dir, v_dir
        half = objs.size_m[k] / 2.0
        actor = actors.get(info.label) if info.source == "synthetic" else None
        if actor is not None and actor.object_class == "person":  # drawn as a disc
            ang = np.linspace(0.0, 2.0 * math.pi, 32, endpoint=False)
            r = actor.size_m[0] / 2.0
            out.append((int(objs.object_class[k]), c + r * np.column_stack([np.cos(ang), np.sin(ang)])))
            continue
        if actor is not None:
            hd = actor_heading_rad(actor, t_s)
            a_dir = np.array([math.cos(hd), math.sin(hd)])  # along travel
            b_dir = np.array([-a_dir[1], a_dir[0]])
            half = np.array(actor.size_m) / 2.0
        corners = np.array(
            [
                c + sa * half[0] * a_dir + sb * half[1] * b_dir
                for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))
            ]
        )
        out.append((int(objs.object_class[k]), corners))
    return out


def project_boxes(
    rects: list[tuple[int, F64]], h_ground_to_image: F64, params: CameraParams, min_visible: float
) -> list[Box]:
    """Axis-aligned image boxes of convex ground outlines: projected, clipped to the image, visibility-filtered."""
    w, h = params.width_px, params.height_px
    lo, hi_u, hi_v = -0.5, w - 0.5, h - 0.5
    bounds = [np.array([1.0, 0.0, -lo]), np.array([-1.0, 0.0, hi_u]), np.array([0.0, 1.0, -lo]),
              np.array([0.0, -1.0, hi_v])]  # fmt: skip
    out: list[Box] = []
    for cls, corners in rects:
        q = np.column_stack([corners, np.ones(len(corners))]) @ h_ground_to_image.T
        if np.any(q[:, 2] <= 1e-9):
            continue  # part of it at or behind the horizon
        px = q[:, :2] / q[:, 2:3]
        full = polygon_area(px)
        if full <= 0.0:
            continue
        clipped = clip_convex_polygon(px, bounds)
        vis = polygon_area(clipped) / full if len(clipped) >= 3 else 0.0
        if vis < min_visible:
            continue
        # pixel-edge coordinates (-0.5 .. W-0.5) -> box edges 0 .. W
        x0, y0 = clipped.min(axis=0) + 0.5
        x1, y1 = clipped.max(axis=0) + 0.5
        if x1 - x0 < 2.0 or y1 - y0 < 2.0:
            continue
        out.append(Box(cls, float(x0), float(y0), float(x1), float(y1), float(vis)))
    return out


def risk_mask(
    world: object, pos: F64, att: F64, t_s: float, params: CameraParams, source_px: F64 | None = None
) -> NDArray[np.uint8]:
    """Risk level (1..5) of the ground seen at every pixel centre; 0 where no footage ground is seen.

    `source_px` (H, W, 2): the ideal-pinhole pixel each pixel shows (a distorted lens: the renderer's
    `distortion_source_map`); None: the pixel itself."""
    from viva_sitl.world import WorldModel

    assert isinstance(world, WorldModel)
    w, h = params.width_px, params.height_px
    if source_px is None:
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        src = np.column_stack([uu.ravel(), vv.ravel()])
    else:
        src = np.asarray(source_px, np.float64).reshape(-1, 2)
    g = pixel_to_ground(src, pos, att, params)
    ok = np.isfinite(g[:, 0])
    geom = world.geometry
    if not geom.unbounded and np.any(ok):
        m = geom.ground_to_px
        q = np.column_stack([g[ok, :2], np.ones(int(ok.sum()))]) @ m.T
        u, v = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
        inside = (u >= -0.5) & (u <= geom.width_px - 0.5) & (v >= -0.5) & (v <= geom.height_px - 0.5)
        idx = np.flatnonzero(ok)
        ok[idx[~inside]] = False
    out = np.zeros(w * h, np.uint8)
    if np.any(ok):
        out[ok] = world.risk_levels_at(g[ok, 0], g[ok, 1], t_s)
    return out.reshape(h, w)


def _region_east_range(world: object, radius_m: float) -> tuple[float, float, float, float]:
    """(n_lo, n_hi, e_lo, e_hi) of the ground poses may look at."""
    from viva_sitl.world import WorldModel

    assert isinstance(world, WorldModel)
    g = world.geometry
    if g.unbounded:
        return -radius_m, radius_m, -radius_m, radius_m
    c = np.array([[-0.5, -0.5, 1.0], [g.width_px - 0.5, -0.5, 1.0], [g.width_px - 0.5, g.height_px - 0.5, 1.0],
                  [-0.5, g.height_px - 0.5, 1.0]]) @ g.px_to_ground.T  # fmt: skip
    ne = c[:, :2] / c[:, 2:3]
    return float(ne[:, 0].min()), float(ne[:, 0].max()), float(ne[:, 1].min()), float(ne[:, 1].max())


def sample_poses(
    world: object, spec: ExportSpec, params: CameraParams, rng: np.random.Generator, want_val: list[bool]
) -> Iterator[tuple[Pose, bool]]:
    """Random poses whose whole footprint lies on the footage and, for the region split, on its side of the cut."""
    from viva_sitl.world import WorldModel

    assert isinstance(world, WorldModel)
    pr = spec.poses
    n_lo, n_hi, e_lo, e_hi = _region_east_range(world, pr.radius_m)
    cut = e_hi - spec.val_fraction * (e_hi - e_lo)
    unbounded = world.geometry.unbounded
    duration = world.tracks.duration_s
    for val in want_val:
        for _ in range(2000):
            alt = rng.uniform(*pr.alt_m)
            tilt = math.radians(rng.uniform(*pr.tilt_deg))
            phi = rng.uniform(0.0, 2.0 * math.pi)
            yaw = math.radians(rng.uniform(*pr.yaw_deg))
            yaw = math.atan2(math.sin(yaw), math.cos(yaw))
            if spec.split == "region":
                lo, hi = (cut, e_hi) if val else (e_lo, cut)
            else:
                lo, hi = e_lo, e_hi
            # an unbounded ground: positions up to `radius` beyond the cut, so a wide footprint fits on its side
            plo, phi_ = (
                (lo, hi)
                if not unbounded or spec.split != "region"
                else ((cut, cut + pr.radius_m) if val else (cut - pr.radius_m, cut))
            )
            pos = np.array([rng.uniform(n_lo, n_hi), rng.uniform(plo, phi_), -alt])
            att = np.array([tilt * math.cos(phi), tilt * math.sin(phi), yaw])
            t = float(rng.uniform(0.0, duration))
            fp = ground_footprint(pos, att, params)
            if fp is None:
                continue
            if not world.geometry.unbounded and not all(world.geometry.contains_ned(n, e) for n, e, _ in fp):
                continue
            if spec.split == "region" and (fp[:, 1].min() < cut if val else fp[:, 1].max() > cut):
                continue
            yield Pose((float(pos[0]), float(pos[1]), float(pos[2])), (float(att[0]), float(att[1]),
                       float(att[2])), t), val  # fmt: skip
            break
        else:
            raise PerceptionError(
                f"no pose within {pr} keeps the view on {world.name}'s {'val' if val else 'train'} ground: "
                "lower the altitude range (--poses alt=LO:HI) or the val fraction"
            )


def export_dataset(
    spec: ExportSpec,
    out_dir: Path,
    progress: Callable[[int, int], None] | None = None,
    shared_dir: Path | None = None,
) -> dict[str, int]:
    """Write the dataset; returns counts {train_images, val_images, boxes}. PerceptionError / FootageError on bad input.

    All or nothing: the dataset is built in `<out_dir>.part` and renamed into place at the end, so bad input, an
    error or Ctrl-C half-way leaves no half-written dataset behind."""
    import shutil

    spec.check()
    out_dir = Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()):
        raise PerceptionError(f"output directory {out_dir} is not empty (choose a new -o)")
    part = out_dir.with_name(out_dir.name + ".part")
    shutil.rmtree(part, ignore_errors=True)
    try:
        counts = _export_into(spec, part, progress, shared_dir)
        if out_dir.exists():
            out_dir.rmdir()  # empty (checked above)
        part.rename(out_dir)
    except BaseException:
        shutil.rmtree(part, ignore_errors=True)
        raise
    return counts


def _export_into(
    spec: ExportSpec,
    out_dir: Path,
    progress: Callable[[int, int], None] | None,
    shared_dir: Path | None,
) -> dict[str, int]:
    import dataclasses

    from viva_sitl.dynamics import EavState
    from viva_sitl.footage import open_footage
    from viva_sitl.sim import Simulator
    from viva_sitl.world import ObjectClass, world_from_source

    params = CameraParams(width_px=spec.width_px, height_px=spec.height_px)
    counts = {"train_images": 0, "val_images": 0, "boxes": 0}
    for split in ("train", "val"):
        for sub in ("images", "labels", "masks", "poses"):
            (out_dir / sub / split).mkdir(parents=True, exist_ok=True)
    root_seq = np.random.SeedSequence(spec.seed)
    total = spec.n * len(spec.footages)
    done = 0
    for fi, (name, seq) in enumerate(zip(spec.footages, root_seq.spawn(len(spec.footages)), strict=True)):
        rng = np.random.default_rng(seq)
        src = open_footage(name, shared_dir=shared_dir)
        world = world_from_source(src)
        with Simulator(footage=src, camera=params) as sim:
            if spec.split == "region":
                want_val = [bool(v) for v in rng.random(spec.n) < spec.val_fraction]
                if spec.n >= 2 and not any(want_val):
                    want_val[-1] = True  # both splits non-empty: ultralytics needs a val set
                if spec.n >= 2 and all(want_val):
                    want_val[0] = False
            else:
                want_val = [name == spec.val_footage] * spec.n
            for i, (pose, val) in enumerate(sample_poses(world, spec, params, rng, want_val)):
                split = "val" if val else "train"
                pos, att = np.array(pose.pos_ned_m), np.array(pose.att_rpy_rad)
                state = EavState.at_rest(pos, yaw_rad=att[2], roll_rad=att[0], pitch_rad=att[1])
                frame = sim.render(dataclasses.replace(state, time_s=pose.time_s), wall_time_s=0.0)
                h_gi = ground_to_image_homography(pos, att, params)
                boxes = project_boxes(ground_rectangles(world, pose.time_s), h_gi, params, spec.min_visible)
                mask = risk_mask(world, pos, att, pose.time_s, params)
                stem = f"f{fi}_{i:05d}"
                ok = cv2.imwrite(str(out_dir / "images" / split / f"{stem}.jpg"), frame.image_bgr,
                                 [cv2.IMWRITE_JPEG_QUALITY, spec.jpeg_quality])  # fmt: skip
                ok = ok and cv2.imwrite(str(out_dir / "masks" / split / f"{stem}.png"), mask)
                if not ok:
                    raise PerceptionError(f"cannot write images under {out_dir}")
                (out_dir / "labels" / split / f"{stem}.txt").write_text(
                    "".join(b.yolo_line(params.width_px, params.height_px) + "\n" for b in boxes)
                )
                meta = {
                    "footage": name,
                    "split": split,
                    "pos_ned_m": pose.pos_ned_m,
                    "att_rpy_rad": pose.att_rpy_rad,
                    "time_s": pose.time_s,
                    "footage_frame_index": frame.meta.footage_frame_index,
                    "width_px": params.width_px,
                    "height_px": params.height_px,
                    "intrinsics_k": camera_intrinsics(params).tolist(),
                    "cam_rot_body": [list(r) for r in frame.meta.cam_rot_body],
                    "ground_to_image_homography": h_gi.tolist(),
                    "coverage": frame.meta.coverage,
                    "boxes_px": [asdict(b) for b in boxes],
                }
                (out_dir / "poses" / split / f"{stem}.json").write_text(json.dumps(meta, indent=1))
                counts[f"{split}_images"] += 1
                counts["boxes"] += len(boxes)
                done += 1
                if progress is not None:
                    progress(done, total)
    names = {int(c): c.label for c in ObjectClass}
    yaml_lines = ["# written by viva-sitl dataset export; paths resolve next to this file",
                  "train: images/train", "val: images/val", "names:"]  # fmt: skip
    yaml_lines += [f"  {k}: {v!r}" for k, v in names.items()]
    (out_dir / "data.yaml").write_text("\n".join(yaml_lines) + "\n")
    spec_json = asdict(spec)
    (out_dir / "export.json").write_text(json.dumps({"spec": spec_json, "counts": counts}, indent=1))
    return counts
