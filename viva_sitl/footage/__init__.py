"""Footage: what the virtual camera looks at, and where its pixels lie on the ground.

    src = open_footage("interchange")          # catalog name, a path, or None / "synthetic" (built-in field)
    idx = src.frame_index_at(t_s)              # floor(t * fps) mod frame_count: deterministic, looping
    img = src.frame(idx)                       # read-only BGR uint8 (H, W, 3)
    src.geometry.px_to_ned(u, v)               # footage pixel -> ground (north, east) m
    src.annotations(idx)                       # [Annotation]: boxes mapped to metres (ground truth for synthetic)

What a source can do beyond whole frames (region reads, decoding ahead, an edgeless ground, ...) it declares in
`source.capabilities` (a `FootageCapabilities`); callers ask that, not the source's type.
Sources: `VideoSource` (PyAV decode: sequential fast path, keyframe seek for jumps), `StillSource` (one image) and
`SyntheticField` (the built-in SYNTHETIC CALIBRATION FIELD: metric grid + markers with analytic trajectories, no
edge: drawn around the camera wherever it flies; more moving `GroundObject`s via `add_object`; walking people, a
crowd and cars with known paths from `synthetic_actors.py`).
Metadata lives in viva_sitl/data/footage/<name>.toml (package data) (see `metadata.py`); DJI .SRT sidecars give the
altitude. Catalog download (`catalog.py`, resume and checksums) and ingest (`ingest.py`, a fast-decoding cache) are
here; their command line, `viva-sitl footage list|info|get|ingest|show|annotate`, is viva_sitl/cli_footage.py.
Errors users can cause raise `FootageError` (a ValueError) with one message.
Threading: use a source from one thread (the renderer's worker); `frame()` is locked, so other callers are
serialised, never corrupt.
"""

from viva_sitl.footage.annotations import Annotation
from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.loader import open_footage, resolve_metadata
from viva_sitl.footage.metadata import AnnotationFormat, CatalogSpec, FootageKind, FootageMetadata
from viva_sitl.footage.source import FootageCapabilities, FootageSource, RegionRead, StillSource, VideoSource
from viva_sitl.footage.srt import SrtSample, SrtTrack, parse_srt, parse_srt_text
from viva_sitl.footage.synthetic import GroundObject, MarkerSpec, SyntheticField, SyntheticFieldParams

__all__ = [
    "Annotation",
    "AnnotationFormat",
    "CatalogSpec",
    "FootageCapabilities",
    "FootageError",
    "FootageGeometry",
    "FootageKind",
    "FootageMetadata",
    "FootageSource",
    "GroundObject",
    "MarkerSpec",
    "RegionRead",
    "SrtSample",
    "SrtTrack",
    "StillSource",
    "SyntheticField",
    "SyntheticFieldParams",
    "VideoSource",
    "open_footage",
    "parse_srt",
    "parse_srt_text",
    "resolve_metadata",
]
