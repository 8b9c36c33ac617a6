"""The named choices of a run, each an enum checked in one place.

Every option that takes one of a few names (the backend, the engine, the JAX precision
mode and search placement, a metric's step mask, how metadata findings count) is a
`Choice`: a `str` enum, so a member equals, hashes, prints and serializes (JSON, pickle
for Ray) as its plain name, and code written against the names keeps working. A front
turns what it was given into a member with `Kind.parse(value)`, which refuses anything
else with one sentence naming the value and the allowed ones.

(`class X(str, Enum)` rather than `enum.StrEnum`, which is Python 3.11's.)
"""

from __future__ import annotations

import enum
import re
from typing import TypeVar

C = TypeVar("C", bound="Choice")


class Choice(str, enum.Enum):
    """A name among a few; `parse` is the one check."""

    def __str__(self) -> str:
        # The plain name in str() and f-strings on every Python (3.12 changed format() of mixed-in enums).
        return self.value

    @classmethod
    def kind(cls) -> str:
        """What the choice is called in messages: the class name in snake case ("metadata_checks")."""
        return re.sub(r"(?<!^)(?=[A-Z])", "_", cls.__name__).lower()

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The allowed names, in declaration order."""
        return tuple(member.value for member in cls)

    @classmethod
    def parse(cls: type[C], value: object) -> C:
        """The member named `value` (a member or its name); ValueError naming the value and the choices."""
        try:
            return cls(value)
        except ValueError:
            raise ValueError(f"unknown {cls.kind()} {value!r}: choose one of {', '.join(cls.names())}") from None


class Backend(Choice):
    """What computes the feature kernels (identical results): numpy, or JAX (the `jax` extra)."""

    NUMPY = "numpy"
    JAX = "jax"


class Engine(Choice):
    """What runs the work (identical results): this host's processes, or a Ray cluster (the `ray` extra)."""

    LOCAL = "local"
    RAY = "ray"


class MetadataChecks(Choice):
    """How a submission's metadata findings count: as the challenge server does, or as warnings."""

    ERROR = "error"
    WARN = "warn"


class Mode(Choice):
    """The precision of a JAX `realism` call (`backends.jax_realism`)."""

    EXACT = "exact"
    FLOAT32 = "float32"


class Search(Choice):
    """Where the JAX path runs its nearest-thing searches (`backends.jax_realism.prepare`)."""

    AUTO = "auto"
    HOST = "host"
    DEVICE = "device"


class Mask(Choice):
    """Which logged steps a metric counts (`metrics.registry.Metric.mask`)."""

    VALID = "valid"  # every valid step
    SPEED = "speed"  # both neighbours valid
    ACCELERATION = "acceleration"  # two valid steps each side
    VEHICLE = "vehicle"  # valid steps of vehicles only
