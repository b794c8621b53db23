"""viva-sitl: a MAVLink SITL autopilot whose vehicle flies inside real nadir footage (ViVa-SAFELAND re-implemented)."""

__version__ = "0.1.0"
