"""Object classes of the world model and how each annotation format's labels map onto them.

World classes: person, bicycle, car, bus, truck, other, and "moving object" (tracks derived from motion, class
unknown). Groups used by queries and scores:
  PEOPLE   = person + bicycle (a bicycle or motorbike carries a rider: a person who can be hurt)
  VEHICLES = car + bus + truck
  MOVING   = moving object (derived tracks: could be either)

Label -> class mapping (case-insensitive; formats with numeric categories are turned into their names first):

  source                    label                                     -> class
  Stanford Drone Dataset    Pedestrian, Skater                        -> person
                            Biker                                     -> bicycle
                            Car, Cart                                 -> car       (Cart: golf cart)
                            Bus                                       -> bus
  VisDrone (categories)     pedestrian(1), people(2)                  -> person
                            bicycle(3), motor(10), tricycle(7),
                            awning-tricycle(8)                        -> bicycle   (ridden)
                            car(4), van(5)                            -> car
                            truck(6) -> truck, bus(9) -> bus, others(11) -> other; ignored-regions(0): dropped
  MOT Challenge (classes)   pedestrian(1), person_on_vehicle(2),
                            static_person(7)                          -> person
                            bicycle(4), motorbike(5)                  -> bicycle
                            car(3) -> car, non_motorized_vehicle(6) -> other; 8..12 (distractor, occluders,
                            reflection): dropped; rows with conf 0 (ignore flag): dropped
  COCO (category names)     person -> person; bicycle, motorcycle -> bicycle; car -> car; bus -> bus;
                            truck, train -> truck; any other name -> other
  Songdo Vision / generic   vehicle -> car; motorcycle -> bicycle; pedestrian, people -> person
  derived (annotate)        moving object -> moving object

A metadata file may override any entry with `[tracks] class_map = { label = "class" }`.
"""

from __future__ import annotations

import enum


class ObjectClass(enum.IntEnum):
    PERSON = 0
    BICYCLE = 1
    CAR = 2
    BUS = 3
    TRUCK = 4
    OTHER = 5
    MOVING = 6  # "moving object": derived from motion, class unknown

    @property
    def label(self) -> str:
        return "moving object" if self is ObjectClass.MOVING else self.name.lower()

    @classmethod
    def parse(cls, text: str) -> ObjectClass:
        key = text.strip().lower()
        for c in cls:
            if c.label == key:
                return c
        raise ValueError(f"unknown object class {text!r} (known: {', '.join(c.label for c in cls)})")


PEOPLE = frozenset({ObjectClass.PERSON, ObjectClass.BICYCLE})
VEHICLES = frozenset({ObjectClass.CAR, ObjectClass.BUS, ObjectClass.TRUCK})
MOVING = frozenset({ObjectClass.MOVING})
ALL = frozenset(ObjectClass)

DROP = None  # a label that maps to DROP is not an object (ignore regions, occluders, reflections)

LABEL_TO_CLASS: dict[str, ObjectClass | None] = {
    # people
    "person": ObjectClass.PERSON,
    "pedestrian": ObjectClass.PERSON,
    "people": ObjectClass.PERSON,
    "skater": ObjectClass.PERSON,
    "person_on_vehicle": ObjectClass.PERSON,
    "static_person": ObjectClass.PERSON,
    # ridden two/three-wheelers
    "bicycle": ObjectClass.BICYCLE,
    "biker": ObjectClass.BICYCLE,
    "motor": ObjectClass.BICYCLE,
    "motorbike": ObjectClass.BICYCLE,
    "motorcycle": ObjectClass.BICYCLE,
    "tricycle": ObjectClass.BICYCLE,
    "awning-tricycle": ObjectClass.BICYCLE,
    # vehicles
    "car": ObjectClass.CAR,
    "cart": ObjectClass.CAR,
    "van": ObjectClass.CAR,
    "vehicle": ObjectClass.CAR,
    "bus": ObjectClass.BUS,
    "truck": ObjectClass.TRUCK,
    "train": ObjectClass.TRUCK,
    "non_motorized_vehicle": ObjectClass.OTHER,
    "others": ObjectClass.OTHER,
    "other": ObjectClass.OTHER,
    "moving object": ObjectClass.MOVING,
    # not objects
    "ignored-regions": DROP,
    "distractor": DROP,
    "occluder": DROP,
    "occluder_on_ground": DROP,
    "occluder_full": DROP,
    "reflection": DROP,
    "crowd": ObjectClass.PERSON,
}


def class_of(label: str, overrides: dict[str, str] | None = None) -> ObjectClass | None:
    """World class of an annotation label (None: not an object, drop it); unknown labels are OTHER."""
    key = label.strip().lower()
    if overrides:
        low = {k.lower(): v for k, v in overrides.items()}
        if key in low:
            return ObjectClass.parse(low[key])
    return LABEL_TO_CLASS.get(key, ObjectClass.OTHER)
