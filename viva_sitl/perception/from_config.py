"""The perception hooks a run's config asks for, built by the layer that wires a vehicle (app, gym): the core takes
them as arguments and never imports perception (sim.py's promise)."""

from __future__ import annotations

from viva_sitl.config import ConfigError, SimConfig
from viva_sitl.perception.config import SRMethod
from viva_sitl.perception.errors import PerceptionError
from viva_sitl.perception.sr import MagnifiedRender, magnified_render_from_config


def super_resolution_from_config(config: SimConfig) -> MagnifiedRender | None:
    """A run's `[perception.sr]` -> what Vehicle(super_resolution=) / Simulator.super_resolution holds (None: method
    none). The model loads here, once per vehicle, so a bad model path or a missing extra is one ConfigError at
    start-up, not a failure at the first low frame."""
    sr = config.perception.sr
    if sr.method is SRMethod.NONE:
        return None
    try:
        return magnified_render_from_config(sr)
    except PerceptionError as exc:
        raise ConfigError(f"[perception.sr]: {exc}") from None


__all__ = ["super_resolution_from_config"]
