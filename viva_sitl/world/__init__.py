"""Ground truth of a footage: who and what is on the ground, when (tracks in NED metres) and the ground risk map.

    from viva_sitl.world import load_world, PEOPLE, VEHICLES
    world = load_world("synthetic")
    hit = world.tracks.nearest(north_m, east_m, t_s, PEOPLE)     # None when nobody is there
    level = world.risk_at(north_m, east_m, t_s)                   # 1..5

Track time follows the footage clock exactly as the camera does (frame floor(t * fps) mod frame_count). Building
reads files (`load_world`, `world_from_source`); queries are pure. See model.py (API), tracks.py (storage, clock,
interpolation), risk.py (levels, polygons), classes.py (label -> class tables).
"""

from viva_sitl.world.classes import ALL, MOVING, PEOPLE, VEHICLES, ObjectClass, class_of
from viva_sitl.world.model import DEFAULT_OBJECT_RISK, ObjectRisk, WorldModel, load_world, world_from_source
from viva_sitl.world.risk import DEFAULT_CLASS_LEVELS, RiskMap
from viva_sitl.world.tracks import Nearest, Objects, TrackInfo, TrackSource, TrackTable, build_tracks

__all__ = [
    "ALL",
    "DEFAULT_CLASS_LEVELS",
    "DEFAULT_OBJECT_RISK",
    "MOVING",
    "PEOPLE",
    "VEHICLES",
    "Nearest",
    "ObjectClass",
    "ObjectRisk",
    "Objects",
    "RiskMap",
    "TrackInfo",
    "TrackSource",
    "TrackTable",
    "WorldModel",
    "build_tracks",
    "class_of",
    "load_world",
    "world_from_source",
]
