"""Parameter tables and the two wire encodings autopilots use for integer parameters.

Why both encodings live here: the traps a factory tool falls into are exactly the differences
between them.  PX4 (``PARAM_ENCODE_BYTEWISE``) puts an int32's four bytes into the float field,
so 197388 travels as a denormal float; ArduPilot (``PARAM_ENCODE_C_CAST``) sends ``float(value)``.
A client using the wrong one writes garbage that the echo may even confirm.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

# MAV_PARAM_TYPE values (common.xml)
UINT8, INT8, UINT16, INT16, UINT32, INT32, REAL32 = 1, 2, 3, 4, 5, 6, 9
INT_TYPES = {UINT8: "<B", INT8: "<b", UINT16: "<H", INT16: "<h", UINT32: "<I", INT32: "<i"}

ParamValue = int | float


@dataclass(frozen=True)
class ParamSpec:
    """One parameter as the firmware declares it."""

    name: str
    type: int
    default: ParamValue
    read_only: bool = False

    @property
    def is_int(self) -> bool:
        return self.type in INT_TYPES


def float32(value: float) -> float:
    """Round to what a float32 parameter holds."""
    return struct.unpack("<f", struct.pack("<f", value))[0]


def bytewise_to_wire(value: ParamValue, ptype: int) -> float:
    """PX4: an integer's little-endian bytes reinterpreted as the float32 on the wire."""
    if ptype not in INT_TYPES:
        return float32(float(value))
    raw = struct.pack(INT_TYPES[ptype], int(value)).ljust(4, b"\x00")
    return struct.unpack("<f", raw)[0]


def bytewise_from_wire(wire: float, ptype: int) -> ParamValue:
    """Reverse of :func:`bytewise_to_wire` (a NaN float field may carry a perfectly good int)."""
    if ptype not in INT_TYPES:
        return float32(wire)
    raw = struct.pack("<f", wire)
    size = struct.calcsize(INT_TYPES[ptype])
    return struct.unpack(INT_TYPES[ptype], raw[:size])[0]


def ccast_from_wire(wire: float, ptype: int) -> ParamValue | None:
    """ArduPilot: the float value itself, truncated toward zero for integer parameters.

    Returns ``None`` for NaN / infinity, which ArduPilot ignores without a reply.
    """
    if not math.isfinite(wire):
        return None
    if ptype in INT_TYPES:
        return int(wire)
    return float32(wire)


class ParamTable:
    """The firmware's parameters: declared specs, values in RAM, and what differs from default."""

    def __init__(self, specs: list[ParamSpec]) -> None:
        self.specs = {s.name: s for s in specs}
        self.names = [s.name for s in specs]
        self.values: dict[str, ParamValue] = {s.name: s.default for s in specs}

    def __contains__(self, name: str) -> bool:
        return name in self.specs

    def index(self, name: str) -> int:
        return self.names.index(name)

    def set(self, name: str, value: ParamValue) -> bool:
        """Store a value of the declared type; return whether it changed."""
        spec = self.specs[name]
        value = int(value) if spec.is_int else float32(float(value))
        changed = self.values[name] != value
        self.values[name] = value
        return changed

    def load(self, stored: dict[str, ParamValue]) -> None:
        """Reset to defaults, then apply what storage holds (unknown names are skipped)."""
        self.values = {s.name: s.default for s in self.specs.values()}
        for name, value in stored.items():
            if name in self.specs:
                self.set(name, value)

    def non_default(self) -> dict[str, ParamValue]:
        return {n: v for n, v in self.values.items() if v != self.specs[n].default}
