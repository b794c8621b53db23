"""Annotations (YOLO boxes per still/frame, MOT-style tracks) mapped into world metres through the footage geometry."""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.metadata import AnnotationFormat


@dataclass(frozen=True)
class Annotation:
    """One labelled object in one footage frame."""

    class_id: int
    label: str
    box_px: tuple[
        float, float, float, float
    ]  # x0, y0, x1, y1: pixel-area edges (as YOLO/MOT), u right, v down
    center_ned_m: tuple[
        float, float
    ]  # (north, east) of the box centre on the ground, m (NED origin = footage centre)
    size_m: tuple[float, float]  # (along footage u, along footage v) ground extent of the box, m
    track_id: int | None = None
    confidence: float | None = None

    @property
    def center_px(self) -> tuple[float, float]:
        """Box centre in pixel-centre coordinates (pixel (0, 0)'s centre is (0, 0), as FootageGeometry.ned_to_px)."""
        x0, y0, x1, y1 = self.box_px
        return (x0 + x1) / 2.0 - 0.5, (y0 + y1) / 2.0 - 0.5


def make_annotation(
    geometry: FootageGeometry,
    class_id: int,
    box_px: tuple[float, float, float, float],
    class_names: tuple[str, ...] = (),
    track_id: int | None = None,
    confidence: float | None = None,
) -> Annotation:
    x0, y0, x1, y1 = box_px
    label = class_names[class_id] if 0 <= class_id < len(class_names) else str(class_id)
    # box_px edges are pixel-area edges; pixel centres are at integers, so the area centre is at (x0+x1)/2 - 0.5
    cu, cv = (x0 + x1) / 2.0 - 0.5, (y0 + y1) / 2.0 - 0.5
    g = geometry.gsd_m_per_px
    return Annotation(
        class_id=class_id,
        label=label,
        box_px=(x0, y0, x1, y1),
        center_ned_m=geometry.px_to_ned(cu, cv),
        size_m=((x1 - x0) * g, (y1 - y0) * g),
        track_id=track_id,
        confidence=confidence,
    )


def parse_yolo(path: Path, geometry: FootageGeometry, class_names: tuple[str, ...] = ()) -> list[Annotation]:
    """YOLO boxes: `class cx cy w h [conf]`, normalised to the image size."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise FootageError(f"cannot read annotations {path}: {exc.strerror or exc}") from None
    w, h = geometry.width_px, geometry.height_px
    out: list[Annotation] = []
    for n, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        try:
            cls = int(float(parts[0]))
            cx, cy, bw, bh = (float(v) for v in parts[1:5])
            conf = float(parts[5]) if len(parts) > 5 else None
        except (ValueError, IndexError):
            raise FootageError(f"{path}:{n}: expected 'class cx cy w h', got {line!r}") from None
        if len(parts) < 5 or not (0 <= bw <= 1.0 and 0 <= bh <= 1.0):
            raise FootageError(f"{path}:{n}: expected normalised 'class cx cy w h', got {line!r}")
        box = ((cx - bw / 2) * w, (cy - bh / 2) * h, (cx + bw / 2) * w, (cy + bh / 2) * h)
        out.append(make_annotation(geometry, cls, box, class_names, confidence=conf))
    return out


def parse_mot(
    path: Path, geometry: FootageGeometry, class_names: tuple[str, ...] = ()
) -> dict[int, list[Annotation]]:
    """MOT-style tracks `frame,id,x,y,w,h[,conf,class,visibility]` (1-based frames, pixels) -> {frame index: boxes}."""
    out: dict[int, list[Annotation]] = {}
    try:
        with path.open(newline="", encoding="utf-8") as f:
            for n, row in enumerate(csv.reader(f), 1):
                row = [c.strip() for c in row if c.strip() != ""]
                if not row or row[0].startswith("#"):
                    continue
                try:
                    frame, tid = int(float(row[0])), int(float(row[1]))
                    x, y, bw, bh = (float(v) for v in row[2:6])
                    conf = float(row[6]) if len(row) > 6 else None
                    cls = int(float(row[7])) if len(row) > 7 else 0
                except (ValueError, IndexError):
                    raise FootageError(
                        f"{path}:{n}: expected 'frame,id,x,y,w,h,...', got {','.join(row)!r}"
                    ) from None
                if frame < 1:
                    raise FootageError(f"{path}:{n}: MOT frames are 1-based, got frame {frame}")
                ann = make_annotation(geometry, max(cls, 0), (x, y, x + bw, y + bh), class_names, tid, conf)
                out.setdefault(frame - 1, []).append(ann)
    except OSError as exc:
        raise FootageError(f"cannot read annotations {path}: {exc.strerror or exc}") from None
    return out


_DIGITS = re.compile(r"(\d+)(?!.*\d)")


class AnnotationStore:
    """Annotations of one footage, loaded on first use; `get(index)` returns that frame's list."""

    def __init__(
        self,
        path: str,
        fmt: AnnotationFormat | None,
        geometry: FootageGeometry,
        class_names: tuple[str, ...] = (),
        still: bool = False,
    ) -> None:
        self._path = Path(path) if path else None
        self._fmt = fmt
        self._geometry = geometry
        self._class_names = class_names
        self._still = still
        self._by_index: dict[int, list[Annotation]] | None = None

    def _load(self) -> dict[int, list[Annotation]]:
        p = self._path
        if p is None or self._fmt is None:
            return {}
        if not p.exists():
            raise FootageError(f"annotations not found: {p}")
        if self._fmt is AnnotationFormat.MOT:
            return parse_mot(p, self._geometry, self._class_names)
        if p.is_dir():  # one YOLO file per frame; the last number in the file name is the 0-based frame index
            out: dict[int, list[Annotation]] = {}
            for f in sorted(p.glob("*.txt")):
                m = _DIGITS.search(f.stem)
                if m is not None:
                    out[int(m.group(1))] = parse_yolo(f, self._geometry, self._class_names)
            return out
        return {0: parse_yolo(p, self._geometry, self._class_names)}

    def get(self, index: int) -> list[Annotation]:
        if self._by_index is None:
            self._by_index = self._load()
        return list(self._by_index.get(0 if self._still else index, ()))
