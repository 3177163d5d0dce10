"""Which magnetometer is being calibrated, told apart from a guess.

Why more than the shell: PX4's MAVLink shell is a NuttX feature.  On POSIX builds (SITL) it is
``pxh`` and answers nothing over MAVLink, and on a line the shell may be busy, disabled or slow.
One missing channel must not make a unit uncalibratable, and it must never be booked as the unit's
FAIL.  So the sensor is identified from the first source that *tells* it:

1. the shell, where it answers: ``listener sensor_mag -i N`` gives every instance's device id;
2. otherwise what the firmware and the station file state together: which SCALED_IMU/2/3 stream
   carries data (sensor_mag instance 0/1/2), the slots' CAL_MAGn_ID, and the product's
   ``magnetometer: <device id>`` / ``options.sensor_instance``.

Where nothing tells (two magnetometers streaming, no device id or instance in the station file),
the unit is not guessed at: a station ERROR names the option to set.  The record keeps which path
identified the sensor.
"""

from __future__ import annotations

from dataclasses import dataclass

from magline.plugin import DutError, StationFault


@dataclass(frozen=True)
class Identified:
    device_id: int
    instance: int  # sensor_mag instance: SCALED_IMU (0), SCALED_IMU2 (1), SCALED_IMU3 (2)
    external: bool | None  # None: not told (the shell alone says it)
    sensors: tuple[int, ...]  # device ids known to be on the unit
    by: str  # how the sensor was identified, for the record


def from_shell(found: list[tuple[int, bool]], wanted: str | int) -> Identified:
    """The shell listed every sensor_mag instance (device id, external)."""
    if not found:
        raise DutError("the PX4 shell lists no sensor_mag instance: no magnetometer detected")
    ids = [d for d, _ in found]
    device_id = ids[0] if wanted == "primary" else _device_id(wanted)
    if device_id not in ids:
        raise DutError(f"magnetometer {device_id} is not on this unit; it has {', '.join(map(str, ids))}")
    instance = ids.index(device_id)
    return Identified(device_id, instance, found[instance][1], tuple(ids), "MAVLink shell (listener sensor_mag)")


def without_shell(streaming: list[int], slot_ids: list[int], wanted: str | int, instance: int | None,
                  why: str) -> Identified:
    """No shell: the streams that carry data, the slots' ids and what the station file states."""
    if not streaming:
        raise DutError("no magnetometer stream (SCALED_IMU/2/3) carries data: no magnetometer detected")
    slots = [i for i in slot_ids if i]
    device_id = None if wanted == "primary" else _device_id(wanted)
    told = []
    if instance is not None:
        if instance not in streaming:
            raise DutError(f"sensor_mag instance {instance} (options.sensor_instance) sends no readings; "
                           f"the unit streams instance{'s' if len(streaming) > 1 else ''} "
                           f"{', '.join(map(str, streaming))}")
        told.append("options.sensor_instance")
    elif len(streaming) == 1:
        instance = streaming[0]
        told.append("the only magnetometer stream")
    if device_id is not None:
        told.append("the station file's device id")
    elif len(streaming) == 1 and len(slots) == 1:
        device_id = slots[0]
        told.append(f"the only CAL_MAGn_ID ({device_id})")
    if instance is None or device_id is None:
        missing = []
        if device_id is None:
            missing.append("products.<part>.magnetometer to the sensor's device id")
        if instance is None:
            missing.append("products.<part>.options.sensor_instance to its sensor_mag instance (0, 1 or 2)")
        raise StationFault(
            f"cannot tell which magnetometer to calibrate: {why}, and the firmware does not say "
            f"({len(streaming)} magnetometer stream(s), CAL_MAGn_ID {', '.join(map(str, slots)) or 'all 0'}); "
            f"set {' and '.join(missing)}")
    known = tuple(dict.fromkeys([device_id, *slots]))
    return Identified(device_id, instance, None, known, "without the shell: " + ", ".join(told))


def _device_id(wanted: str | int) -> int:
    if isinstance(wanted, int) or str(wanted).isdigit():
        return int(wanted)
    raise DutError(f"magnetometer {wanted!r}: give a device id or 'primary'")
