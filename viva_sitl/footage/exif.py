"""The recording scale of a photo from its own metadata: DJI XMP (drone-dji:*) and EXIF (Pillow).

    read_photo_scale(path) -> PhotoScale(relative_altitude_m, hfov_deg, lat_deg, lon_deg, heading_deg, source)

- XMP is XML text inside the JPEG's APP1 segment; DJI writes `drone-dji:RelativeAltitude="+87.30"` (metres above
  the take-off point), `drone-dji:GpsLatitude` / `GpsLongitude`, `drone-dji:GimbalYawDegree` (bearing of the image
  top for a nadir gimbal) and `drone-dji:GimbalPitchDegree` (-90 = nadir), as attributes or as elements. They are
  found by a text scan of the file's first bytes (the XMP packet is plain UTF-8), no XML library needed.
- EXIF (Pillow): FocalLengthIn35mmFilm (0xA405) gives the diagonal FoV of a 35 mm-equivalent lens,
  2 atan(21.63 mm / f35) (CIPA: the 35 mm equivalent is defined on the 43.27 mm diagonal); else the camera Model
  (0x0110) is looked up in DJI_DIAGONAL_FOV_DEG. The horizontal FoV then follows from the picture's aspect:
  hfov = 2 atan(tan(dfov / 2) * w / sqrt(w^2 + h^2)).
Anything unreadable is simply absent (None): the caller falls back to the next source, never fails.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

XMP_SCAN_BYTES = 512 * 1024  # DJI writes the XMP packet in the first APP1 segments, well inside this
HALF_DIAGONAL_35MM = 21.633  # mm: half of the 36 x 24 mm frame's diagonal

# DJI camera EXIF Model -> published (diagonal) field of view in degrees, from DJI's product specifications.
DJI_DIAGONAL_FOV_DEG: dict[str, float] = {
    "FC8482": 82.1,  # Mini 4 Pro
    "FC3582": 82.1,  # Mini 3 Pro
    "FC3682": 82.1,  # Mini 3
    "FC7303": 83.0,  # Mini 2 / Mini SE
    "FC7203": 83.0,  # Mavic Mini
    "FC3170": 84.0,  # Mavic Air 2
    "FC3411": 88.0,  # Air 2S
    "FC8282": 82.0,  # Air 3 (wide camera)
    "L2D-20C": 84.0,  # Mavic 3 (Hasselblad)
    "M3E": 84.0,  # Mavic 3 Enterprise (wide)
    "L1D-20C": 77.0,  # Mavic 2 Pro
    "FC2103": 85.0,  # Mavic Air
    "FC220": 78.8,  # Mavic Pro
    "FC6310": 84.0,  # Phantom 4 Pro / Advanced
    "FC6310S": 84.0,  # Phantom 4 Pro V2.0
    "FC6310R": 84.0,  # Phantom 4 RTK
    "FC330": 94.0,  # Phantom 4
    "FC300X": 94.0,  # Phantom 3 Professional / Advanced
    "FC1102": 81.9,  # Spark
}

_NUM = rb"([+-]?\d+(?:\.\d+)?)"


@dataclass(frozen=True)
class PhotoScale:
    relative_altitude_m: float | None = None
    hfov_deg: float | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    heading_deg: float | None = None
    gimbal_pitch_deg: float | None = None
    source: str = ""  # what was found, for logs: "XMP RelativeAltitude, EXIF FocalLengthIn35mmFilm 24 mm"


def _xmp_number(head: bytes, tag: str) -> float | None:
    m = re.search(rb"drone-dji:" + tag.encode() + rb"\s*(?:=\s*[\"']|>)\s*" + _NUM, head)
    if m is None:
        return None
    v = float(m.group(1))
    return v if math.isfinite(v) else None


def hfov_from_diagonal(dfov_deg: float, width_px: int, height_px: int) -> float:
    """Horizontal FoV of a pinhole picture of this size whose diagonal FoV is `dfov_deg`."""
    diag = math.hypot(width_px, height_px)
    return math.degrees(2.0 * math.atan(math.tan(math.radians(dfov_deg) / 2.0) * width_px / diag))


def read_photo_scale(path: Path) -> PhotoScale:
    """What the photo's XMP/EXIF say about its recording (every field None when absent or unreadable)."""
    try:
        with path.open("rb") as f:
            head = f.read(XMP_SCAN_BYTES)
    except OSError:
        return PhotoScale()
    found: list[str] = []
    alt = _xmp_number(head, "RelativeAltitude")
    if alt is not None:
        found.append(f"XMP RelativeAltitude {alt:g} m")
    lat, lon = _xmp_number(head, "GpsLatitude"), _xmp_number(head, "GpsLongitude")
    if lat is None or lon is None or not (-90 <= lat <= 90 and -180 <= lon <= 180) or (lat == 0 and lon == 0):
        lat = lon = None
    heading = _xmp_number(head, "GimbalYawDegree")
    pitch = _xmp_number(head, "GimbalPitchDegree")
    hfov = _exif_hfov(path, found)
    return PhotoScale(
        relative_altitude_m=alt,
        hfov_deg=hfov,
        lat_deg=lat,
        lon_deg=lon,
        heading_deg=heading % 360.0 if heading is not None else None,
        gimbal_pitch_deg=pitch,
        source=", ".join(found),
    )


def _exif_hfov(path: Path, found: list[str]) -> float | None:
    try:
        from PIL import Image, UnidentifiedImageError
    except ImportError:  # pragma: no cover - Pillow is a dependency
        return None
    try:
        with Image.open(path) as im:
            width, height = im.size
            exif = im.getexif()
            model = str(exif.get(0x0110, "") or "").strip().strip("\x00")
            f35 = exif.get_ifd(0x8769).get(0xA405)
    except (OSError, UnidentifiedImageError, ValueError, SyntaxError) as exc:
        log.debug("%s: no EXIF (%s)", path, exc)
        return None
    if width <= 0 or height <= 0:
        return None
    try:
        f35_mm = float(f35) if f35 is not None else 0.0
    except (TypeError, ValueError):
        f35_mm = 0.0
    if f35_mm > 0 and math.isfinite(f35_mm):
        found.append(f"EXIF FocalLengthIn35mmFilm {f35_mm:g} mm")
        dfov = math.degrees(2.0 * math.atan(HALF_DIAGONAL_35MM / f35_mm))
        return hfov_from_diagonal(dfov, width, height)
    dfov_table = DJI_DIAGONAL_FOV_DEG.get(model.upper())
    if dfov_table is not None:
        found.append(f"EXIF Model {model} (FoV {dfov_table:g} deg diagonal)")
        return hfov_from_diagonal(dfov_table, width, height)
    return None
