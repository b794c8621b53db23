"""viva-sitl: a MAVLink SITL autopilot whose vehicle flies inside real nadir footage (ViVa-SAFELAND re-implemented)."""

from viva_sitl import opencv_pool as _opencv_pool

__version__ = "0.1.0"

# before anything here imports cv2: OpenCV's pool sleeps instead of spinning between calls (see viva_sitl.opencv_pool)
_opencv_pool.configure()
