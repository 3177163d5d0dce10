"""What a DUT backend is: the autopilot-specific half of a calibration.

Why a Protocol rather than hooks for every call: a backend holds a live link (a MAVLink socket,
an in-process simulator) whose state spans the whole run, so it is an object created per unit by
the factory a plugin registers through ``magline_register_dut_backends``.  The core's default
phase hooks drive it; a plugin can still replace a whole phase through the phase hooks.

Units: everything crossing this interface is in µT and the fit's convention
``m_cal = S·(m_raw − h)``; conversion to Gauss / milligauss and to the autopilot's sign
convention happens inside :meth:`DutBackend.calibration_params`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, TypeVar, runtime_checkable

from magline.core.faults import StationFault

if TYPE_CHECKING:
    from numpy.typing import NDArray
    from pydantic import BaseModel

    from magline.core.fit import FitResult
    from magline.core.mounting import ImuSeries
    from magline.core.station.schema import Product

ParamValue = int | float


def float32_equal(a: float, b: float) -> bool:
    """Equal as the float32 MAVLink carries a parameter in (1.05 reads back as 1.0499999523): the same
    float32, exactly.  Why no tolerance: a near-diagonal soft iron writes an off-diagonal term of
    −4e-7, and "within 1e-6" took a stale echo of its old 0 for the new value's."""
    import numpy as np  # here: numpy is not needed to start a command

    return bool(np.float32(a) == np.float32(b)) or (math.isnan(a) and math.isnan(b))


def param_equal(written: ParamValue, echoed: ParamValue) -> bool:
    """A parameter read back (or echoed) is the value written: an integer exactly (a firmware may echo
    it as a whole float), a float at float32 precision."""
    if isinstance(written, int) and not isinstance(written, bool):
        return (isinstance(echoed, int) and echoed == written) or (
            isinstance(echoed, float) and echoed.is_integer() and int(echoed) == written)
    return float32_equal(float(written), float(echoed))


class DutError(RuntimeError):
    """The unit itself failed: its firmware refused the calibration, its magnetometer is missing, the
    calibration did not survive the power cycle.  The sequencer books the unit as FAIL."""


class LinkError(DutError, StationFault):
    """The station could not talk to the unit: nothing answers, the link was lost or closed, a
    deadline of the station's own link passed.  The sequencer books the unit as ERROR (it was not
    judged).  A subclass of :class:`DutError` so that code which only cleans up after any DUT
    problem (``except DutError``) keeps working."""


class UnansweredRequest(DutError, StationFault):
    """The vehicle talks, but not to this request, after every retry, and nothing proves its firmware
    lacks the name (ArduPilot and PX4 ignore an unknown name without a reply, as a link that loses the
    answers looks): nothing proves the unit bad.  The sequencer books the unit as ERROR (it was not
    judged).  A backend that can prove the name missing (PX4's parameter list, ArduPilot's answers in
    the order asked) raises a :class:`DutError` naming it instead: a FAIL."""


def prove_unechoed_write(name: str, value: ParamValue, unanswered: str, read: Callable[[], ParamValue]) -> ParamValue:
    """A PARAM_SET that got no echo proves nothing by itself: its echoes may have been lost, the write
    ignored, or the name unknown to the firmware (ArduPilot and PX4 v1.13–v1.16 answer those with
    silence).  The parameter read back decides: the value written — it took, returned; another — the
    write was ignored (:class:`DutError`: FAIL); no answer — nothing proven (:class:`UnansweredRequest`:
    ERROR).  ``unanswered`` says the write in the backend's words; ``read()`` reads ``name``."""
    try:
        held = read()
    except UnansweredRequest:
        raise UnansweredRequest(f"{unanswered}, and {name} cannot be read either (a name this firmware does not "
                                "know, or answers lost on the link): the unit is not judged") from None
    same = held == value if isinstance(value, int) else float32_equal(float(held), float(value))
    if not same:
        raise DutError(f"{unanswered}, and {name} still reads {held:g}: the autopilot ignored the write")
    return held


class OldBootRunning(DutError):
    """After a reboot or power cut the vehicle still runs the boot it ran before (its uptime kept
    counting).  After a commanded reboot the firmware refused it: the unit FAILs.  After a supply cut
    the cut never reached the board — it is powered by USB too — and the power control makes it the
    station's fault (:func:`magline.core.power.await_boot_after_cut`)."""

    def __init__(self, message: str, uptime_s: float) -> None:
        super().__init__(message)
        self.uptime_s = uptime_s


class NotRestored(DutError):
    """:meth:`DutBackend.restore` could not put back what :meth:`DutBackend.prepare` changed.

    ``left_changed`` names each parameter with the value it is left at and the one it should have
    (``{"COMPASS_LEARN": "0 (was 3)"}``); ``cause`` is the real reason (usually the link).  The unit
    must not ship: the sequencer tells the record and the operator to re-test it.
    """

    def __init__(self, cause: str, left_changed: dict[str, str]) -> None:
        changed = ", ".join(f"{k} left at {v}" for k, v in left_changed.items())
        super().__init__(f"the unit could not be restored ({cause}): {changed}")
        self.cause = cause
        self.left_changed = left_changed


@dataclass
class Magnetometer:
    """One magnetometer as the unit's firmware configures it (what the mounting check compares with).

    ``orientation``: the firmware's orientation value for this sensor (MAV_SENSOR_ORIENTATION numbers:
    ArduPilot ``COMPASS_ORIENTn``, PX4 ``CAL_MAGn_ROT``), i.e. how the firmware believes the sensor is
    mounted; ``readings_rotated``: the streamed readings have that rotation applied already (ArduPilot's
    calibration frame is the body frame) rather than being in the sensor's own axes (PX4's sensor_mag);
    ``fix_params``: the parameter name(s) a different orientation is written to, empty when the firmware
    cannot hold one for this sensor (PX4's internal magnetometers follow the board).
    """

    device_id: int
    label: str  # the firmware's own name for it: "compass 2", "CAL_MAG1"
    external: bool | None = None
    orientation: int = 0
    readings_rotated: bool = False
    fix_params: list[str] = field(default_factory=list)
    # the largest field the readings can carry (µT): beyond it a reading is clipped.  A MAVLink int16
    # milligauss field ends at ±3276.7 µT; None: not known (the fit then guesses from plateaus)
    range_ut: float | None = None
    # the rotation the firmware applies where it is no discrete value (PX4's CAL_MAGn_ROT = 100 with its
    # custom Euler angles): ``v_body = rotation · v_sensor``, rows; None: ``orientation`` says it all
    rotation: list[list[float]] | None = None
    # each reading is the mean of the driver's samples, taken this often (Hz), since the firmware last read the
    # sensor (ArduPilot); 0: each reading is one sample.  The fit takes readings averaged while the unit turned
    # back to their window's middle
    averaged_sample_hz: float = 0.0


@dataclass
class UnitInfo:
    """Who answered on the link.

    ``magnetometers``: every magnetometer the unit has, in the firmware's order (the first is the
    primary); a backend that calibrates one sensor only may leave it empty — the core then knows just
    ``selected_sensor``."""

    autopilot: str
    firmware: str
    sensors: list[int]  # device ids of the magnetometers present
    selected_sensor: int  # device id being calibrated (the primary)
    soft_iron_model: Literal["full", "diagonal"] = "full"  # what the autopilot can hold
    extra: dict[str, Any] = field(default_factory=dict)
    magnetometers: list[Magnetometer] = field(default_factory=list)


def empty_series() -> NDArray:
    """A series of no readings (what a chunk carries of a stream it has none of).  A function: NumPy is
    imported on a unit's first chunk, not by every command that loads the plugins."""
    import numpy as np

    return np.empty(0)


@dataclass
class SampleChunk:
    """Distinct raw readings of the selected magnetometer, µT, with their time stamps (ms).

    A backend whose stream repeats readings (a stream faster than the sensor) passes each reading
    once and says in ``repeats`` how many copies it dropped since the previous chunk.
    """

    mag_ut: NDArray  # rows of raw readings, µT, on the sensor's axes
    t_ms: NDArray  # each reading's stamp, ms, on the accelerometer's clock
    # the sensor's temperature per reading where the stream has it: the fit then tests the warm-up on it
    # (a drifting offset against temperature, not only against time)
    temp_c: NDArray | None = None
    repeats: int = 0  # copies of a reading the backend dropped since the previous chunk
    # the other magnetometers' distinct readings that arrived meanwhile, by device id (same clock)
    more: dict[int, SampleChunk] = field(default_factory=dict)
    # the unit's accelerometer (and gyro) readings that arrived meanwhile, body axes, same clock
    imu: ImuSeries | None = None
    # the unit's own battery current readings that arrived meanwhile (A), once :meth:`CompensatesCurrent.
    # measure_current_interference` asked for them; empty otherwise
    current_a: NDArray = field(default_factory=empty_series)
    current_t_ms: NDArray = field(default_factory=empty_series)  # the stream's time when each arrived
    # current reports meanwhile that said the unit measures no current (MAVLink's −1, PX4's −1 A): a battery
    # monitor without a current sensor, which no sweep can be fitted against
    current_unmeasured: int = 0


@runtime_checkable
class DutBackend(Protocol):
    def connect(self) -> UnitInfo:
        """Open the link, identify the autopilot and its magnetometers."""

    def prepare(self) -> None:
        """Stop the firmware rewriting calibration during the test (auto-learning, in-flight
        calibration) and remember what to restore.  Change RAM only where you can: whatever
        ``prepare`` changes, :meth:`restore` must put back in RAM *and* storage, because the
        calibration's own commit (:meth:`commit`) saves every parameter, including the ones
        ``prepare`` switched off — a ``restore`` that writes RAM only ships the unit with its
        auto-calibration off after the next power cycle."""

    def samples(self, rate_hz: float) -> Iterator[SampleChunk]:
        """Stream raw (uncalibrated) readings until the caller stops iterating, each reading once
        (copies a fast stream repeats are dropped and counted in ``SampleChunk.repeats``).

        Several magnetometers (see ``use_magnetometers`` below): the primary's readings in ``mag_ut``,
        every other chosen sensor's in ``more[device_id]``, each with its own repeats dropped and its
        own time stamps; the accelerometer's readings in ``imu`` (m/s², body axes) on the same clock —
        the mounting check pairs them by time.  A backend without an accelerometer leaves ``imu`` None:
        the station then cannot prove the mounting (an ERROR unless the product says
        ``orientation: skip``).

        Pacing: yield readings as the sensor delivers them (block on the link); never faster than
        the sensor, and never invent readings to reach ``rate_hz`` — it is the rate to *ask* the
        firmware for; the core counts distinct readings against ``acquisition.samples`` and its
        own ``timeout_s``.  ``t_ms``: the sensor's (or the stream's) own clock in milliseconds,
        increasing; where it starts does not matter (only differences are used).  The generator
        must stop its stream when closed (``close()`` / ``GeneratorExit``), and raise
        :class:`LinkError` at once when the link is lost — not after a silent timeout."""

    def calibration_params(self, fit: FitResult) -> dict[str, ParamValue]:
        """Map a fit to this autopilot's parameters (units and sign convention applied here).

        With several magnetometers the core calls ``calibration_params(fit, sensor=device_id)`` for each
        sensor; a backend that lists ``UnitInfo.magnetometers`` must accept that keyword."""

    def read_params(self, names: list[str]) -> dict[str, ParamValue]:
        """Read parameters from the DUT."""

    def write_params(self, params: dict[str, ParamValue]) -> dict[str, ParamValue]:
        """Write parameters; return the values the DUT echoed (raise DutError when refused)."""

    def commit(self) -> None:
        """Force the parameters to non-volatile storage."""

    def reboot(self) -> None:
        """Command a reboot over the link (what the default ``link-reboot`` power method uses).  A DUT
        without such a command raises :class:`DutError`; its station then names a power control
        that cuts the supply (``scpi-supply``, ``command``), and the record's ``persistence.method``
        says which one proved the power cycle."""

    def release_link(self) -> None:
        """Close the link: the power is about to be cut and the vehicle will vanish."""

    def await_boot(self, since: float) -> dict[str, float]:
        """Reconnect after a reboot or power-on at ``since`` (``time.monotonic()``) and prove it is a
        new boot; return figures (``time_to_heartbeat_s``, ``uptime_at_reconnect_s``).

        :func:`await_new_boot` does the proving: its ``reconnect(remaining_s)`` must itself keep
        retrying until the vehicle answers or ``remaining_s`` runs out (a vehicle still booting
        refuses connections), because ``await_new_boot`` gives up at the first error it gets."""

    def selected_sensor_present(self) -> bool:
        """After a power cycle: is the calibrated sensor still there with the same id?"""

    # Optional capabilities: the Protocols below (``isinstance(dut, ReportsUptime)`` …); a backend has a
    # capability by having the method, nothing to declare.

    def persistence_problems(self) -> list[str]:
        """After a power cycle, once the calibrated output was read: what the autopilot itself says is
        wrong with the calibration (ArduPilot: "Compass not calibrated" when the device id was not saved);
        empty when fine.  A backend may ask its firmware as soon as the new boot is proven and read the
        answer here."""

    def restore(self) -> None:
        """Put back what :meth:`prepare` changed, in RAM *and* storage (called at the end of every run,
        also on errors); raise :class:`NotRestored` naming what is left changed when it cannot."""

    def close(self) -> None:
        """Release the link."""


# ---------------------------------------------------------------------------------------------- optional
# What some backends can do and others cannot.  Why Protocols and not methods on DutBackend: a backend
# without the capability must not pretend to have it (a default that returns "nothing" would read as
# "checked, nothing wrong"); the core asks ``isinstance(dut, Capability)`` and says what it skipped.


@runtime_checkable
class CalibratesSeveral(Protocol):
    """A unit with several magnetometers: after ``connect``, stream and calibrate these (primary first)."""

    def use_magnetometers(self, device_ids: list[int]) -> None: ...


@runtime_checkable
class ReportsSensorsPresent(Protocol):
    """After a power cycle: the device ids the unit has now (a unit of several is checked sensor by sensor)."""

    def sensors_present(self) -> list[int]: ...


@runtime_checkable
class WritesOrientation(Protocol):
    """The parameters that make the firmware take the sensor as mounted in firmware orientation ``value``
    (names from ``Magnetometer.fix_params``): the mounting check's advice names them."""

    def orientation_params(self, device_id: int, value: int) -> dict[str, ParamValue]: ...


@runtime_checkable
class WritesRotation(Protocol):
    """The parameters that make the firmware turn the sensor's axes into the body by ``rotation`` (3×3,
    any angle: PX4's custom Euler angles), for a product with ``misalignment: write``; raises
    :class:`DutError` saying why when this sensor cannot hold one."""

    def rotation_params(self, device_id: int, rotation: NDArray) -> dict[str, ParamValue]: ...


@runtime_checkable
class StoresFactoryCalibration(Protocol):
    """A firmware store for the calibration that survives a reset of the parameters (PX4's
    ``/fs/mtd_caldata``), for a product with ``persist: factory-storage``.

    ``store_factory_calibration(mode_after)`` is called in the persist phase after the parameters are
    written and saved: it has the firmware copy them into its store, leaves the store's mode setting at
    ``mode_after`` (saved) and returns what the firmware said; the firmware refusing or failing raises
    :class:`DutError` with the firmware's own words (the unit is then an ERROR whose parameters are still
    proven).  ``factory_store_contents(written)`` (after the power cycle): for each of the ``written``
    parameters the store is meant to hold, the value it holds (None: it holds none; a value the firmware
    shows rounded is the written one where it is within that rounding), or None as a whole where the
    firmware does not let a station read the store.  ``restore_from_factory_store(since)``: the proof the
    product may ask for (``prove_factory_restore``) — reset the calibration parameters so the store alone
    can bring them back, reboot, await the new boot, and return what the store's names read back."""

    def store_factory_calibration(self, mode_after: int) -> str: ...

    def factory_store_contents(self, written: dict[str, ParamValue]) -> dict[str, ParamValue | None] | None: ...

    def restore_from_factory_store(self, since: float) -> dict[str, ParamValue]: ...


@runtime_checkable
class ReportsUptime(Protocol):
    """Seconds since the autopilot booted (MAVLink SYSTEM_TIME's ``time_boot_ms``), None when it does not
    answer; ``acquisition.warm_up_s`` waits on it (without it: the whole time, counted from the moment asked)."""

    def uptime_s(self) -> float | None: ...


@runtime_checkable
class HasBootTimeout(Protocol):
    """How long the unit may take to boot after a power cycle (the operator's countdown shows it)."""

    boot_timeout_s: float


@runtime_checkable
class CompensatesCurrent(Protocol):
    """A firmware that reports the current it draws and can cancel its compasses' current interference
    (ArduPilot's COMPASS_MOTCT = 2 with COMPASS_MOTn_*, PX4's CAL_MAG_COMP_TYP with
    CAL_MAGn_xCOMP).

    ``measure_current_interference(compensation=False)``: before a sweep — its battery current streamed
    with :meth:`DutBackend.samples` (``SampleChunk.current_a``) and the firmware's compensation switched
    off (what it corrects must not hide the field being measured; :meth:`DutBackend.restore` puts it back
    unless the calibration's write replaced it); ``compensation=True`` (the proof after the power cycle)
    leaves what the firmware holds on and reads whatever the stream needs anew.

    ``left_per_amp_ut(device_id, stream_per_amp_ut)``: from the slope the proof sweep saw in the raw
    stream (µT per amp of the unit's reading), what the firmware's *corrected* output still changes per
    amp with the parameters it holds now (body axes) — ArduPilot streams its corrected field, PX4's
    SCALED_IMU is the raw sensor, so only the backend knows which.

    ``interference_params(device_id, per_amp_ut, fit)``: the parameters that cancel ``per_amp_ut`` — the
    field change per amp of the firmware's *own* current reading, µT/A, in the frame the backend streams
    its raw readings in — for a sensor calibrated with ``fit``, in the firmware's frame, units and sign;
    raise :class:`DutError` naming what is missing when this firmware cannot hold it.

    ``compensation_missing(device_id)``: before the sweep, what this firmware lacks to hold the
    compensation of ``device_id`` (its parameters, by name), or ``None`` when it can — it writes nothing
    and records nothing to be written (a backend may remember the answer for the connection), so a unit
    that cannot be compensated is not held at the sweep's ends for a slope nobody will write.

    ``compensation_params()``: what switches the compensation on (written once with the
    calibration)."""

    def measure_current_interference(self, compensation: bool = False) -> None: ...

    def interference_params(self, device_id: int, per_amp_ut: NDArray, fit: FitResult) -> dict[str, ParamValue]: ...

    def compensation_missing(self, device_id: int) -> str | None: ...

    def compensation_params(self) -> dict[str, ParamValue]: ...

    def left_per_amp_ut(self, device_id: int, stream_per_amp_ut: NDArray) -> NDArray: ...


@runtime_checkable
class RunsMotorTest(Protocol):
    """``motor_test(throttle_pct, seconds)``: one motor spun at that throttle for that long (MAVLink
    MAV_CMD_DO_MOTOR_TEST; props off — the station asks before every unit); raise :class:`DutError` when
    the firmware refuses it."""

    def motor_test(self, throttle_pct: float, seconds: float) -> None: ...


@runtime_checkable
class ReadsCalibratedField(Protocol):
    """After the power cycle, ``count`` readings (µT, rows) of the firmware's own *calibrated* output for
    this sensor (``sensor``: its device id, for a unit of several) — ArduPilot's corrected stream, PX4's
    HIGHRES_IMU; None when it cannot be attributed to this sensor.  The verify phase holds their
    magnitude to the reference."""

    def calibrated_field_ut(self, count: int, sensor: int | None = None) -> NDArray | None: ...


@runtime_checkable
class ReadsCalibratedFields(Protocol):
    """The same for several sensors read side by side (ArduPilot's compasses stream at 10 Hz each: one
    after the other, a three-compass unit waits three times as long)."""

    def calibrated_fields_ut(self, count: int, device_ids: list[int]) -> dict[int, NDArray | None]: ...


@dataclass(frozen=True)
class CalibratedBesideRaw:
    """The firmware's calibrated readings (µT, body axes, rows) each beside the raw reading of every
    calibrated sensor it may have been made from (``raw_ut``: device id → rows, µT, the sensor's own
    axes), with the rotation the firmware turns each sensor's calibrated reading into the body by
    (``to_body``: device id → 3×3, as it holds it now: board or sensor rotation, level adjustment).
    ``less_estimated_bias``: the calibrated readings are the calibration's output less the firmware's own
    online estimate of the compass's bias (PX4's HIGHRES_IMU less EKF2's), which learns, from the boot on,
    the field's difference to the firmware's model of it."""

    calibrated_ut: NDArray
    raw_ut: dict[int, NDArray]
    to_body: dict[int, NDArray]
    less_estimated_bias: bool = False


@runtime_checkable
class ReadsRawAndCalibrated(Protocol):
    """The firmware's calibrated output beside the raw readings it was made from, None where it cannot
    tell — what proves the firmware *applies* magline's calibration, vector by vector."""

    def raw_and_calibrated_ut(self, count: int) -> CalibratedBesideRaw | None: ...


DutFactory = Callable[["Product", Any], DutBackend]  # (the product entry, its validated options)

OptionsModel = TypeVar("OptionsModel", bound="BaseModel")


FAIR_ATTEMPT_S = 2.0  # the least a reconnect is given once the old boot answered (see await_new_boot)
# Set while a power control awaits the boot after it cut the power (:func:`after_power_cut`): a backend's
# ``await_boot`` keeps its signature, and :func:`await_new_boot` learns that an old boot is final.
_AFTER_CUT: ContextVar[bool] = ContextVar("magline_after_power_cut", default=False)


@contextmanager
def after_power_cut() -> Iterator[None]:
    """Within it, :func:`await_new_boot` takes the first answer from the old boot as the answer.  Why:
    after a commanded reboot the old boot may answer for a moment before it goes down, so the wait runs
    to its timeout; once the power was cut and restored no old boot is about to go down — a board that
    answers with its old uptime ran through the cut, and waiting out the boot timeout (30 s by default)
    only kept the operator from the cause."""
    token = _AFTER_CUT.set(True)
    try:
        yield
    finally:
        _AFTER_CUT.reset(token)


def await_new_boot(reconnect: Callable[[float], None], uptime_s: Callable[[], float | None], started: float,
                   timeout_s: float, poll_s: float = 0.3) -> tuple[float, float]:
    """After a reboot / power-on at ``started`` (monotonic), reconnect until the vehicle proves a new boot.

    Why the uptime check: right after the command the old boot may still answer (PX4 waits 400 ms,
    a UDP link never closes), and a read-back from it would prove nothing.  A boot whose uptime is
    shorter than the time since the command is the new one.  ``reconnect(remaining_s)`` opens a
    fresh link or raises :class:`DutError`; ``uptime_s()`` returns the vehicle's uptime or ``None``.
    Returns (seconds from the command to the new boot's link, its uptime then).

    Once the old boot has answered, every attempt gets at least ``FAIR_ATTEMPT_S`` even past the
    deadline.  Why: a reconnect is not instant (a MAVSDK server starts, a serial port opens); the
    attempt begun with a tenth of a second left failed on a loaded machine, and a board that ran
    through a supply cut was reported as one that "did not come back" — its old boot unproven, the
    cause wrong.  A board that rebooted and is still down fails a fair attempt as before.
    """
    deadline = started + timeout_s
    told = False  # did the vehicle ever say its uptime?
    last_uptime = 0.0
    while True:
        time.sleep(poll_s)
        try:
            reconnect(max(deadline - time.monotonic(), FAIR_ATTEMPT_S if told else 0.1))
        except DutError as exc:
            raise LinkError(f"the vehicle did not come back within {timeout_s:g} s of the power cycle "
                            f"(last attempt: {exc})") from None
        reconnected = time.monotonic() - started
        uptime = uptime_s()
        last_uptime = uptime if uptime is not None else last_uptime
        if uptime is not None and uptime < reconnected:
            return reconnected, uptime
        told = told or uptime is not None
        if uptime is not None and _AFTER_CUT.get():
            raise OldBootRunning(f"the vehicle still runs its old boot after the power cut: up {uptime:.0f} s, "
                                 f"{reconnected:.1f} s after the power came back", uptime)
        if time.monotonic() > deadline:
            if not told:  # no answer is no proof of an old boot: the station could not judge
                raise LinkError(f"the vehicle answered after the power cycle but never said its uptime within "
                                f"{timeout_s:g} s: the new boot is not proven")
            raise OldBootRunning(f"the vehicle still runs its old boot {timeout_s:g} s after the reboot command "
                                 f"(reboot refused?): up {last_uptime:.0f} s", last_uptime)


def require_same_vehicle(system_id: int, answered: int, connection: str, uid: int = 0, answered_uid: int = 0) -> None:
    """After a power cycle: the vehicle that answered must be the unit under test.  Another MAVLink
    system on the link (a cable moved, a second board) proves nothing about this unit: an ERROR.
    Boards of one product usually share a system id, so the hardware UID (AUTOPILOT_VERSION ``uid``)
    is compared too where both boots report one (0: the firmware does not say)."""
    if answered != system_id:
        raise LinkError(f"after the power cycle a vehicle with MAVLink system id {answered} answered on "
                        f"{connection}, not the unit under test (system id {system_id}): the unit's calibration "
                        "is not proven")
    if uid and answered_uid and uid != answered_uid:
        raise LinkError(f"after the power cycle the vehicle on {connection} reports hardware UID {answered_uid:#x}, "
                        f"not the unit under test's ({uid:#x}): another board with the same system id; the unit's "
                        "calibration is not proven")


def validated_options(model: type[OptionsModel], options: dict[str, Any], owner: str,
                      station_dir: Path | str | None = None) -> OptionsModel:
    """Validate a plugin's ``options`` from the station file; the error names every bad key.  The station
    file's folder goes into the validation context, where a :data:`~magline.plugin.StationPath` option
    resolves a relative path against it."""
    from pydantic import ValidationError

    from magline.core.station.paths import STATION_DIR

    try:
        return model.model_validate(options, context={STATION_DIR: station_dir})
    except ValidationError as exc:
        problems = "; ".join(f"options.{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
        raise ValueError(f"{owner}: {problems}") from exc
