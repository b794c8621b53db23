"""Configuration of the Virtual Aerial Camera (VAC): intrinsics, mount, extrinsics, fill colour, effects."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

# Off-footage fill colour (BGR): magenta, a colour that real nadir footage practically never contains, so regions
# outside the footage are obvious on screen. `RenderResult.coverage` reports them numerically (the geofence).
DEFAULT_FILL_BGR: tuple[int, int, int] = (255, 0, 255)


class Mount(enum.Enum):
    """How the camera is attached to the vehicle."""

    FIXED = "fixed"  # rigid on the body (the paper's equation): roll and pitch tilt the view
    GIMBAL = "gimbal"  # roll/pitch stabilised (as the DJI that recorded the footage); yaw follows the body


@dataclass(frozen=True)
class CameraParams:
    """The VAC. Default: 640x480, 82.1 deg horizontal FoV (DJI Mini 4 Pro), rigid nadir mount, no effects.

    Default nadir mount: optical axis = body +z (down), image x (right) = body +y (right), image y (down) = body -x
    (backward), so the vehicle's nose points to the top of the image. `mount_*_deg` rotate the camera away from that
    default as if the body were rotated by (roll, pitch, yaw) in FRD: `mount_pitch_deg = +30` tilts the camera 30 deg
    forward (it then sees what the default camera sees when the vehicle pitches its nose up by 30 deg).
    """

    width_px: int = 640
    height_px: int = 480
    hfov_deg: float = 82.1  # horizontal field of view of the ideal pinhole (before lens distortion)
    vfov_deg: float | None = None  # None: derived from the aspect ratio with square pixels
    mount: Mount = Mount.FIXED
    mount_roll_deg: float = 0.0  # camera rotation offsets from the default nadir mount (FRD, ZYX)
    mount_pitch_deg: float = 0.0
    mount_yaw_deg: float = 0.0
    cam_pos_body_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # T^b_v: camera centre in FRD (m)
    fill_bgr: tuple[int, int, int] = DEFAULT_FILL_BGR  # colour of VAC pixels that see no footage
    antialias: bool = True  # False: always warp the full-resolution frame (aliases; for comparisons)
    lod_bias: float = 0.0  # added to log2(footage px per VAC px) before choosing the pyramid level
    trilinear: bool = True  # blend the two nearest pyramid levels (False: nearest-below level only)
    motion_blur: bool = False  # blur along the image-projected velocity over the exposure
    exposure_s: float = 0.01  # exposure time used by motion_blur (s)
    noise_std: float = 0.0  # Gaussian sensor noise, standard deviation in 8-bit levels (needs a Generator)
    k1: float = 0.0  # radial lens distortion (OpenCV/Brown model, normalised image coordinates)
    k2: float = 0.0

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise ValueError(f"camera {name} must be a positive integer, got {v!r}")
        if self.width_px > 16384 or self.height_px > 16384:
            raise ValueError(f"camera size {self.width_px}x{self.height_px} is larger than 16384 px")
        if not (math.isfinite(self.hfov_deg) and 0.0 < self.hfov_deg < 179.0):
            raise ValueError(f"camera hfov_deg must be in (0, 179), got {self.hfov_deg!r}")
        if self.vfov_deg is not None and not (math.isfinite(self.vfov_deg) and 0.0 < self.vfov_deg < 179.0):
            raise ValueError(f"camera vfov_deg must be in (0, 179) or None, got {self.vfov_deg!r}")
        if not isinstance(self.mount, Mount):
            raise ValueError(f"camera mount must be a Mount, got {self.mount!r}")
        for name in ("mount_roll_deg", "mount_pitch_deg", "mount_yaw_deg", "lod_bias", "k1", "k2"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"camera {name} must be finite, got {getattr(self, name)!r}")
        if len(self.cam_pos_body_m) != 3 or not all(math.isfinite(v) for v in self.cam_pos_body_m):
            raise ValueError(f"camera cam_pos_body_m must be 3 finite numbers, got {self.cam_pos_body_m!r}")
        if len(self.fill_bgr) != 3 or not all(
            isinstance(c, int) and not isinstance(c, bool) and 0 <= c <= 255 for c in self.fill_bgr
        ):
            raise ValueError(f"camera fill_bgr must be 3 integers in 0..255, got {self.fill_bgr!r}")
        if not (math.isfinite(self.exposure_s) and self.exposure_s >= 0.0):
            raise ValueError(f"camera exposure_s must be >= 0, got {self.exposure_s!r}")
        if not (math.isfinite(self.noise_std) and self.noise_std >= 0.0):
            raise ValueError(f"camera noise_std must be >= 0, got {self.noise_std!r}")

    @property
    def vfov_effective_deg(self) -> float:
        """Vertical FoV: the configured one, else from the aspect ratio with square pixels."""
        if self.vfov_deg is not None:
            return self.vfov_deg
        t = math.tan(math.radians(self.hfov_deg) / 2.0) * self.height_px / self.width_px
        return math.degrees(2.0 * math.atan(t))

    @property
    def has_distortion(self) -> bool:
        return self.k1 != 0.0 or self.k2 != 0.0
