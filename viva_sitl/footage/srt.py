"""DJI .SRT telemetry sidecars: per-frame altitude (`rel_alt:`) and position, as the reference code reads them.

Hand-written (a few regular expressions): the format is a subtitle file whose text is `[key: value]` fields, and no
maintained library parses the DJI variants. Handled forms (Mini 3/4, Air 2S, Mavic 3):

    1
    00:00:00,000 --> 00:00:00,033
    <font size="28">FrameCnt: 1, DiffTime: 33ms
    2024-05-14 10:21:34.123
    [iso: 100] ... [latitude: 19.432600] [longitude: -99.133200] [rel_alt: 52.300 abs_alt: 2290.512] ...</font>

and the older `GPS(lon,lat,alt)`/`H 52.3m` form (`[lat: ..] [lon: ..]` spellings are accepted too).
"""

from __future__ import annotations

import re
import statistics
from dataclasses import dataclass
from pathlib import Path

from viva_sitl.footage.errors import FootageError

_NUM = r"([-+]?\d+(?:\.\d+)?)"
_TIME = re.compile(r"(\d+):(\d+):(\d+)[,.](\d+)\s*-->\s*(\d+):(\d+):(\d+)[,.](\d+)")
_REL_ALT = re.compile(r"rel_alt\s*:\s*" + _NUM)
_ABS_ALT = re.compile(r"abs_alt\s*:\s*" + _NUM)
_LAT = re.compile(r"\[\s*lat(?:itude)?\s*:\s*" + _NUM)
_LON = re.compile(r"\[\s*lon(?:gitude|g)?\s*:\s*" + _NUM)
_GPS = re.compile(r"GPS\s*\(\s*" + _NUM + r"\s*,\s*" + _NUM + r"(?:\s*,\s*" + _NUM + r")?\s*\)")
_H = re.compile(r"\bH\s*" + _NUM + r"\s*m\b")


@dataclass(frozen=True)
class SrtSample:
    index: int  # subtitle number (1-based, as in the file)
    start_s: float
    end_s: float
    rel_alt_m: float | None = None  # altitude above the take-off point
    abs_alt_m: float | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None


@dataclass(frozen=True)
class SrtTrack:
    samples: tuple[SrtSample, ...]

    @property
    def rel_alt_m(self) -> float | None:
        """Median relative altitude (the footage is recorded in hover; the median ignores a stray first sample)."""
        alts = [s.rel_alt_m for s in self.samples if s.rel_alt_m is not None]
        return float(statistics.median(alts)) if alts else None

    @property
    def first_rel_alt_m(self) -> float | None:
        """The first `rel_alt:` value (what the reference implementation uses)."""
        return next((s.rel_alt_m for s in self.samples if s.rel_alt_m is not None), None)

    @property
    def lat_lon_deg(self) -> tuple[float, float] | None:
        """Median position, ignoring (0, 0) fixes (DJI writes zeros before GPS lock)."""
        pts = [
            (s.lat_deg, s.lon_deg)
            for s in self.samples
            if s.lat_deg is not None and s.lon_deg is not None and (s.lat_deg, s.lon_deg) != (0.0, 0.0)
        ]
        if not pts:
            return None
        return float(statistics.median(p[0] for p in pts)), float(statistics.median(p[1] for p in pts))


def _seconds(h: str, m: str, s: str, frac: str) -> float:
    return int(h) * 3600 + int(m) * 60 + int(s) + int(frac) / 10 ** len(frac)


def parse_srt_text(text: str) -> SrtTrack:
    """Parse the text of a DJI .SRT file (blocks separated by blank lines)."""
    samples: list[SrtSample] = []
    for block in re.split(r"\r?\n\s*\r?\n", text.strip()):
        lines = block.strip().splitlines()
        if len(lines) < 2:
            continue
        t = _TIME.search(block)
        if t is None:
            continue
        g = t.groups()
        try:
            index = int(lines[0].strip().lstrip("\ufeff"))
        except ValueError:
            index = len(samples) + 1
        rel = _REL_ALT.search(block)
        absa = _ABS_ALT.search(block)
        lat = _LAT.search(block)
        lon = _LON.search(block)
        lat_v = float(lat.group(1)) if lat else None
        lon_v = float(lon.group(1)) if lon else None
        rel_v = float(rel.group(1)) if rel else None
        gps = _GPS.search(block)
        if gps and lat_v is None:
            lon_v, lat_v = float(gps.group(1)), float(gps.group(2))  # GPS(lon, lat, alt)
        if rel_v is None and (h := _H.search(block)):
            rel_v = float(h.group(1))
        samples.append(
            SrtSample(
                index=index,
                start_s=_seconds(*g[:4]),
                end_s=_seconds(*g[4:]),
                rel_alt_m=rel_v,
                abs_alt_m=float(absa.group(1)) if absa else None,
                lat_deg=lat_v,
                lon_deg=lon_v,
            )
        )
    return SrtTrack(tuple(samples))


def parse_srt(path: str | Path) -> SrtTrack:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise FootageError(f"cannot read SRT sidecar {p}: {exc.strerror or exc}") from None
    track = parse_srt_text(text)
    if not track.samples:
        raise FootageError(f"{p} has no SRT subtitle blocks (is it a DJI .SRT sidecar?)")
    return track


def find_srt_sidecar(video: Path) -> Path | None:
    """`clip.SRT` / `clip.srt` beside `clip.MP4`, as DJI writes them."""
    for ext in (".SRT", ".srt"):
        cand = video.with_suffix(ext)
        if cand.is_file():
            return cand
    return None
