"""Box/track files users bring, read into one row type (`BoxRow`: frame, track, label, pixel box, lost, occluded).

Formats (`TrackFormat`), all boxes in footage pixels (pixel-area edges, taken as given), frames as 0-based footage
frame indices:
  sdd          Stanford Drone Dataset annotations.txt: `track_id xmin ymin xmax ymax frame lost occluded generated
               "label"` (0-based frames; lost = 1: out of view, not present; occluded = 1: present but hidden)
  motchallenge MOT Challenge gt.txt/det.txt: `frame,id,left,top,w,h,conf,class,visibility` (1-based frames; conf 0 =
               ignore this row; class ids -> names below; visibility < 0.5 -> occluded). Rows with fewer columns
               (results files) are pedestrians.
  visdrone     VisDrone-MOT: `frame,id,left,top,w,h,score,category,truncation,occlusion` (1-based frames; score 0 or
               category 0 = ignored region, dropped; occlusion >= 1 -> occluded)
  coco         COCO json: images[], annotations[] (`bbox` = [x, y, w, h]), categories[]; the frame of an image is its
               `frame_id`/`frame_index` if given, else the last number in its file name, else its rank by id; a
               `track_id`/`instance_id` on an annotation links boxes into tracks
  viva         our own CSV (written by `viva-sitl footage annotate`): header
               `frame,track_id,label,x0_px,y0_px,x1_px,y1_px,lost,occluded,confidence,derived`, '#' comments
The existing `[annotations]` yolo/mot files are read by annotations.py and turned into rows by the world loader.
Every error names the file and line in one message (FootageError).
"""

from __future__ import annotations

import contextlib
import csv
import enum
import json
import os
import re
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple

from viva_sitl.footage.errors import FootageError


class TrackFormat(enum.Enum):
    SDD = "sdd"
    MOTCHALLENGE = "motchallenge"
    VISDRONE = "visdrone"
    COCO = "coco"
    VIVA = "viva"
    YOLO = "yolo"  # per still / per-frame folder (annotations.py)
    MOT = "mot"  # MOT-style with class indices into class_names (annotations.py)


class BoxRow(NamedTuple):
    frame: int  # 0-based footage frame index
    track_id: int | None  # None: an untracked detection (one object in one frame)
    label: str  # the format's own class name (world/classes.py maps it)
    x0_px: float
    y0_px: float
    x1_px: float
    y1_px: float
    lost: bool = False  # not in view in this frame (not present)
    occluded: bool = False  # in view but hidden (present)
    confidence: float | None = None
    derived: bool = False  # made by a program (annotate), not by a person


MOTCHALLENGE_CLASSES = {
    1: "pedestrian", 2: "person_on_vehicle", 3: "car", 4: "bicycle", 5: "motorbike", 6: "non_motorized_vehicle",
    7: "static_person", 8: "distractor", 9: "occluder", 10: "occluder_on_ground", 11: "occluder_full",
    12: "reflection",
}  # fmt: skip
VISDRONE_CLASSES = {
    0: "ignored-regions", 1: "pedestrian", 2: "people", 3: "bicycle", 4: "car", 5: "van", 6: "truck",
    7: "tricycle", 8: "awning-tricycle", 9: "bus", 10: "motor", 11: "others",
}  # fmt: skip


def _read_lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise FootageError(f"cannot read tracks {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise FootageError(f"tracks {path} is not a text file") from None


def parse_sdd(path: Path) -> list[BoxRow]:
    out: list[BoxRow] = []
    for n, line in enumerate(_read_lines(path), 1):
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split(maxsplit=9)
        try:
            tid, x0, y0, x1, y1, frame, lost, occ = (int(p) for p in parts[:8])
            label = parts[9].strip().strip('"')
        except (ValueError, IndexError):
            raise FootageError(
                f"{path}:{n}: expected 'id xmin ymin xmax ymax frame lost occluded generated \"label\"', got {line!r}"
            ) from None
        out.append(BoxRow(frame, tid, label, x0, y0, x1, y1, lost == 1, occ == 1, None, False))
    return out


def _csv_rows(path: Path) -> Iterable[tuple[int, list[str]]]:
    for n, line in enumerate(_read_lines(path), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        yield n, [c.strip() for c in line.replace(" ", ",").split(",") if c.strip() != ""]


def parse_motchallenge(path: Path) -> list[BoxRow]:
    out: list[BoxRow] = []
    for n, row in _csv_rows(path):
        try:
            frame, tid = int(float(row[0])), int(float(row[1]))
            x, y, w, h = (float(v) for v in row[2:6])
            conf = float(row[6]) if len(row) > 6 else 1.0
            cls = int(float(row[7])) if len(row) > 7 else -1
            vis = float(row[8]) if len(row) > 8 else 1.0
        except (ValueError, IndexError):
            raise FootageError(
                f"{path}:{n}: expected 'frame,id,left,top,w,h,conf,class,visibility'"
            ) from None
        if frame < 1:
            raise FootageError(f"{path}:{n}: MOT Challenge frames are 1-based, got {frame}")
        is_gt = len(row) >= 9 and cls >= 1
        if is_gt and conf == 0:
            continue  # the ground truth's "ignore" flag
        label = MOTCHALLENGE_CLASSES.get(cls, f"class-{cls}") if is_gt else "pedestrian"
        out.append(
            BoxRow(frame - 1, tid, label, x, y, x + w, y + h, False, vis < 0.5, None if is_gt else conf)
        )
    return out


def parse_visdrone(path: Path) -> list[BoxRow]:
    out: list[BoxRow] = []
    for n, row in _csv_rows(path):
        try:
            frame, tid = int(row[0]), int(row[1])
            x, y, w, h = (float(v) for v in row[2:6])
            score, cat = float(row[6]), int(row[7])
            occ = int(row[9]) if len(row) > 9 else 0
        except (ValueError, IndexError):
            raise FootageError(
                f"{path}:{n}: expected 'frame,id,left,top,w,h,score,category,truncation,occlusion'"
            ) from None
        if frame < 1:
            raise FootageError(f"{path}:{n}: VisDrone frames are 1-based, got {frame}")
        if score == 0 or cat == 0:
            continue  # ignored region
        label = VISDRONE_CLASSES.get(cat, f"class-{cat}")
        out.append(BoxRow(frame - 1, tid, label, x, y, x + w, y + h, False, occ >= 1, None))
    return out


_LAST_NUMBER = re.compile(r"(\d+)(?!.*\d)")


def parse_coco(path: Path) -> list[BoxRow]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise FootageError(f"cannot read tracks {path}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FootageError(f"{path} is not valid COCO json: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("annotations"), list):
        raise FootageError(f"{path}: COCO json needs an 'annotations' list")
    images: list[dict[str, Any]] = [i for i in data.get("images", []) if isinstance(i, dict)]
    cats = {
        c.get("id"): str(c.get("name", c.get("id")))
        for c in data.get("categories", [])
        if isinstance(c, dict)
    }
    frame_of: dict[Any, int] = {}
    for rank, img in enumerate(sorted(images, key=lambda i: str(i.get("id")))):
        f = img.get("frame_id", img.get("frame_index"))
        if f is None:
            m = _LAST_NUMBER.search(Path(str(img.get("file_name", ""))).stem)
            f = int(m.group(1)) if m is not None and len(images) > 1 else (rank if len(images) > 1 else 0)
        frame_of[img.get("id")] = int(f)
    out: list[BoxRow] = []
    for k, a in enumerate(data["annotations"]):
        try:
            x, y, w, h = (float(v) for v in a["bbox"])
            frame = frame_of.get(a.get("image_id"), 0) if frame_of else 0
            label = cats.get(a.get("category_id"), str(a.get("category_id")))
            tid = a.get("track_id", a.get("instance_id"))
        except (KeyError, TypeError, ValueError):
            raise FootageError(f"{path}: annotation #{k} needs bbox [x, y, w, h] and image_id") from None
        if a.get("iscrowd"):
            label = "crowd"
        out.append(BoxRow(frame, int(tid) if tid is not None else None, label, x, y, x + w, y + h, False, False,
                          float(a["score"]) if "score" in a else None))  # fmt: skip
    return out


VIVA_HEADER = ("frame", "track_id", "label", "x0_px", "y0_px", "x1_px", "y1_px", "lost", "occluded", "confidence",
               "derived")  # fmt: skip


def parse_viva(path: Path) -> list[BoxRow]:
    out: list[BoxRow] = []
    lines = [(n, ln) for n, ln in enumerate(_read_lines(path), 1) if ln.strip() and not ln.startswith("#")]
    if not lines or tuple(c.strip() for c in lines[0][1].split(",")) != VIVA_HEADER:
        raise FootageError(f"{path}: expected the header {','.join(VIVA_HEADER)}")
    for (n, _), row in zip(lines[1:], csv.reader(ln for _, ln in lines[1:]), strict=True):
        try:
            out.append(BoxRow(int(row[0]), int(row[1]) if row[1] else None, row[2], float(row[3]), float(row[4]),
                              float(row[5]), float(row[6]), row[7] == "1", row[8] == "1",
                              float(row[9]) if row[9] else None, row[10] == "1"))  # fmt: skip
        except (ValueError, IndexError):
            raise FootageError(f"{path}:{n}: expected {len(VIVA_HEADER)} comma-separated values") from None
    return out


def write_viva(path: Path, rows: Iterable[BoxRow], comment: str = "") -> Path:
    """Write rows atomically: a temp file in the same folder, renamed over `path` only when complete."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    try:
        with os.fdopen(fd, "w", newline="", encoding="utf-8") as f:
            for line in comment.splitlines():
                f.write(f"# {line}\n")
            w = csv.writer(f, lineterminator="\n")
            w.writerow(VIVA_HEADER)
            for r in rows:
                w.writerow([r.frame, "" if r.track_id is None else r.track_id, r.label, f"{r.x0_px:.2f}",
                            f"{r.y0_px:.2f}", f"{r.x1_px:.2f}", f"{r.y1_px:.2f}", int(r.lost), int(r.occluded),
                            "" if r.confidence is None else f"{r.confidence:.3f}", int(r.derived)])  # fmt: skip
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; the result is an ordinary file
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


PARSERS = {
    TrackFormat.SDD: parse_sdd,
    TrackFormat.MOTCHALLENGE: parse_motchallenge,
    TrackFormat.VISDRONE: parse_visdrone,
    TrackFormat.COCO: parse_coco,
    TrackFormat.VIVA: parse_viva,
}


def read_boxes(path: Path, fmt: TrackFormat) -> list[BoxRow]:
    if not Path(path).is_file():
        raise FootageError(f"tracks not found: {path}")
    parser = PARSERS.get(fmt)
    if parser is None:
        raise FootageError(f"{path}: format {fmt.value} is read through [annotations], not [tracks]")
    return parser(Path(path))
