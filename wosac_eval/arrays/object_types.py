"""The object types of a track: the codes of the Scenario proto's `Track.ObjectType`, named once.

Every room that tells vehicles from pedestrians reads these: the metrics (time
to collision and red lights count vehicles), the validation messages (the
proto names), the analyses and results (the short names, per object type), the
demo scenes. They live with the arrays because `object_type` is one of the
arrays' columns.
"""

from __future__ import annotations

TYPE_UNSET, TYPE_VEHICLE, TYPE_PEDESTRIAN, TYPE_CYCLIST, TYPE_OTHER = 0, 1, 2, 3, 4

# Code -> the enum value's name in the proto (as messages about a submission name it).
PROTO_NAMES: dict[int, str] = {
    TYPE_VEHICLE: "TYPE_VEHICLE",
    TYPE_PEDESTRIAN: "TYPE_PEDESTRIAN",
    TYPE_CYCLIST: "TYPE_CYCLIST",
    TYPE_OTHER: "TYPE_OTHER",
}

# Code -> the short name results use, for the types analysed apart (`by_object_type`), in display order.
# TYPE_OTHER is scored with the others but not reported apart.
SHORT_NAMES: dict[int, str] = {TYPE_VEHICLE: "vehicle", TYPE_PEDESTRIAN: "pedestrian", TYPE_CYCLIST: "cyclist"}
ANALYSED_TYPES: tuple[str, ...] = tuple(SHORT_NAMES.values())
