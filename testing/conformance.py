"""Conformance suites: the contracts of magline's plugin kinds, checked against an author's own.

``check_result_sink(open_sink, folder)`` drives a sink exactly as the sequencer does and fails
with the broken rule of :mod:`magline.core.results.contract` (run ids, the ``history`` shape,
raw data stored before the verdict, storage that outlives the process's handle).  magline's own
stores run it in magline's CI.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from magline.core.dut import ReadsCalibratedField, ReadsCalibratedFields, ReadsRawAndCalibrated, ReportsUptime
from magline.core.fit.samples_csv import RawSamples
from magline.core.record import AttemptRecord, Outcome, RunRecord
from magline.core.results.contract import HistoryAttempt, HistoryRun, ResultSink
from magline.core.verify.calibrated_output import estimated_bias_allowance_ut
from magline.testing.builders import make_record

# The DUT capabilities :func:`check_dut_backend` requires although the core does without them (the
# contract page says so beside each): why each one, in the words its failure gives.
REQUIRED_DUT_CAPABILITIES: dict[type, str] = {
    ReadsCalibratedField: "the firmware's own calibrated output after the power cycle proves the conversion "
                          "of units and signs (a backend that cannot attribute it to the sensor returns None)",
}


def _attempt(n: int, accepted: bool) -> AttemptRecord:
    rng = np.random.default_rng(n)
    raw = RawSamples(mag_ut=rng.normal(size=(50, 3)) * 40.0, t_ms=np.arange(50) * 20.0)
    return AttemptRecord(attempt=n, samples=50, coverage=0.9, target=0.6, raw=raw, accepted=accepted,
                         refused=None if accepted else "coverage 20 % below the target 60 %")


def _unit(sink: Any, serial: str, verdict: Outcome, begin: bool = True) -> RunRecord:
    record = make_record(serial=serial, part="CONFORMANCE-1", verdict=Outcome.ERROR)  # the sequencer's start value
    if begin:
        sink.begin(record)
        assert isinstance(record.run_id, int), f"begin() must set record.run_id to an int (got {record.run_id!r})"
    for n, accepted in ((1, False), (2, True)):
        attempt = _attempt(n, accepted)
        record.attempts.append(attempt)
        sink.save_attempt(record, attempt)
        assert isinstance(record.run_id, int), "save_attempt() without begin() must begin the run (set run_id)"
    record.verdict, record.finished = verdict, "2026-11-24T12:00:00+00:00"
    record.cause = "" if verdict is Outcome.PASS else "hard_iron_norm_ut = 400 µT outside [—, 300]"
    sink.finish(record)
    return record


def _check_shape(run: dict, serial: str) -> None:
    for key in HistoryRun.__annotations__:
        assert key in run, f"history() rows need the key {key!r} (see magline.plugin.HistoryRun)"
    assert run["serial"] == serial and isinstance(run["id"], int) and isinstance(run["verdict"], str)
    assert isinstance(run["attempts"], list) and isinstance(run["failed"], list)
    for attempt in run["attempts"]:
        missing = [k for k in HistoryAttempt.__annotations__ if k not in attempt]
        assert not missing, f"history() attempts need the keys {missing}"


def check_result_sink(open_sink: Callable[[Path], Any], folder: str | Path) -> None:
    """Run the results-sink contract: ``open_sink(folder)`` opens your sink on a store in ``folder``
    (called twice: the second time it must find what the first stored)."""
    folder = Path(folder)
    sink = open_sink(folder)
    assert isinstance(sink, ResultSink), ("the sink lacks part of the contract: begin, save_attempt, finish, "
                                          "history, close (magline.plugin.ResultSink)")
    try:
        first = _unit(sink, "CONF-1", Outcome.PASS)
        second = _unit(sink, "CONF-2", Outcome.FAIL)
        third = _unit(sink, "CONF-1", Outcome.PASS, begin=False)
        ids = [first.run_id, second.run_id, third.run_id]
        assert ids == sorted(ids) and len(set(ids)) == 3, f"run ids must be unique and increasing (got {ids})"
        assert sink.history("NOT-THERE") == [], "history() of an unknown serial is an empty list"
    finally:
        sink.close()
    sink = open_sink(folder)  # a new handle on the same store: the records outlive the first one
    try:
        runs = sink.history("CONF-1")
        assert [r["id"] for r in runs] == [first.run_id, third.run_id], (
            f"history('CONF-1') must list its two runs oldest first, from a new handle on the store (got {runs})")
        for run in runs:
            _check_shape(run, "CONF-1")
        assert [len(r["attempts"]) for r in runs] == [2, 2], "every saved attempt is in the history"
        failed = sink.history("CONF-2")
        assert failed and failed[0]["verdict"] == "fail" and failed[0]["cause"], "the verdict and cause are stored"
    finally:
        sink.close()


# --------------------------------------------------------------------------- DUT backends


def _power_cycle(dut: Any) -> dict:
    from magline.core.power import LinkReboot

    return LinkReboot().cycle(dut)


def _stream(dut: Any, count: int, rate_hz: float) -> tuple[np.ndarray, np.ndarray, float]:
    """``count`` readings from ``samples()``, checking each chunk; the generator closed at the end."""
    from magline.core.dut import SampleChunk

    mags, times, got = [], [], 0
    started = time.monotonic()
    stream = dut.samples(rate_hz)
    _stream.more, _stream.imu = {}, []
    try:
        for chunk in stream:
            assert isinstance(chunk, SampleChunk), f"samples() must yield SampleChunk (got {type(chunk).__name__})"
            mag, t_ms = _rows(chunk, "the primary magnetometer")
            mags.append(mag)
            times.append(t_ms)
            for device_id, more in chunk.more.items():
                _stream.more.setdefault(device_id, []).append(_rows(more, f"magnetometer {device_id} (more)"))
            if chunk.imu is not None:
                _stream.imu.append(chunk.imu)
            got += len(mag)
            if got >= count:
                break
    finally:
        stream.close()  # a closable stream: the backend stops it (GeneratorExit)
    wall = time.monotonic() - started
    t_ms = np.concatenate(times)
    assert np.all(np.diff(t_ms) > 0), "t_ms must increase from reading to reading (each distinct reading once)"
    return np.vstack(mags)[:count], t_ms[:count], wall


def _rows(chunk: Any, what: str) -> tuple[np.ndarray, np.ndarray]:
    mag, t_ms = np.atleast_2d(np.asarray(chunk.mag_ut, float)), np.atleast_1d(np.asarray(chunk.t_ms, float))
    if mag.size == 0:
        mag = mag.reshape(0, 3)
    assert mag.shape[1:] == (3,) and len(t_ms) == len(mag), f"{what}: a chunk holds (n, 3) readings and n times"
    assert np.all(np.isfinite(mag)) and np.all(np.isfinite(t_ms)), f"{what}: readings and times must be finite"
    return mag, t_ms


def _check_more_and_imu(info: Any, t_ms: np.ndarray, field_ut: float, accelerometer: bool) -> dict:
    """Several magnetometers: each listed one streams in ``more`` on the same clock, in µT; the
    accelerometer: gravity in m/s² (body axes) over the same time."""
    from magline.core.fit import FitOptions, FitRefused, fit_calibration

    figures: dict[str, Any] = {}
    others = [m.device_id for m in info.magnetometers if m.device_id != info.selected_sensor]
    for device_id in others:
        parts = _stream.more.get(device_id)
        assert parts, (f"magnetometer {device_id} is in UnitInfo.magnetometers but samples() sent none of its "
                       "readings in SampleChunk.more (after use_magnetometers)")
        mag = np.vstack([m for m, _ in parts])
        times = np.concatenate([t for _, t in parts])
        assert np.all(np.diff(times) > 0), f"magnetometer {device_id}: t_ms must increase (each reading once)"
        assert times[0] < t_ms[-1] and times[-1] > t_ms[0], (
            f"magnetometer {device_id}'s time stamps do not overlap the primary's: one clock for every sensor")
        try:
            fit = fit_calibration(mag, FitOptions(field_ut=field_ut, coverage_bins=40, model=info.soft_iron_model))
        except FitRefused as exc:
            raise AssertionError(f"magnetometer {device_id}'s readings do not determine a calibration "
                                 f"({exc.message})") from None
        ratio = fit.field_estimate_ut / field_ut
        assert 0.7 < ratio < 1.3, f"magnetometer {device_id}'s readings have a radius of {ratio:.2f}× the field: µT"
        figures[f"fit_{device_id}"] = fit
    if accelerometer:
        assert _stream.imu, ("samples() sent no accelerometer readings (SampleChunk.imu): the station cannot prove "
                             "the mounting (pass accelerometer=False for a device without one)")
        acc = np.vstack([np.asarray(i.accel_mss, float) for i in _stream.imu])
        acc_t = np.concatenate([np.asarray(i.t_ms, float) for i in _stream.imu])
        g = float(np.median(np.linalg.norm(acc, axis=1)))
        assert 8.5 < g < 11.0, f"the accelerometer reads {g:.3g} at rest: it must be in m/s² (9.81 = 1 g)"
        assert acc_t[0] < t_ms[-1] and acc_t[-1] > t_ms[0], "the accelerometer's time stamps are on another clock"
        figures["gravity_mss"] = g
    return figures


def check_dut_backend(open_dut: Callable[[], Any], field_ut: float, *, samples: int = 400, rate_hz: float = 50.0,
                      prepare_params: tuple[str, ...] | list[str] = (), hard_iron_ut: Any = None,
                      power_cycle: Callable[[Any], dict] | None = None, tolerance_pct: float = 3.0,
                      unsaved_writes: str = "lost", accelerometer: bool = True) -> dict:
    """Run the DUT-backend contract (:class:`magline.plugin.DutBackend`) against ``open_dut()``, a
    backend connected to a device (or its simulator) that is being tumbled in a field of
    ``field_ut`` µT.  Checks, in order, each failing with the rule it breaks:

    identification; ``uptime_s()``, where offered, in seconds and the new boot's after a power cycle;
    a paced, closable stream of distinct readings in µT (a sphere fit of them has
    the field's radius; with ``hard_iron_ut``, the device's known offset); the float32 echo of a
    write; unsaved writes lost on a power cycle; a proven new boot; a committed calibration read
    back after it and the firmware's *calibrated* output reading ``field_ut`` (sign, unit and matrix
    convention of ``calibration_params``); ``restore()`` undoing ``prepare()`` in storage (for the
    parameters named in ``prepare_params``).

    ``power_cycle(dut) -> figures`` defaults to the
    ``link-reboot`` method.  ``unsaved_writes``: what a power cycle does to a write that was not
    committed — ``"lost"`` (the firmware saves only on ``commit()``), ``"kept"`` (it stores every
    write at once, as ArduPilot) or ``"unspecified"`` (it saves on its own schedule, as PX4's
    autosave 300 ms after a change: only ``commit()`` is a guarantee).

    Several magnetometers
    (``UnitInfo.magnetometers``): after ``use_magnetometers`` with all of them, each streams in
    ``SampleChunk.more`` on the same clock, in µT; ``accelerometer``: the stream carries gravity in m/s²
    (``SampleChunk.imu``) for the mounting check.  Returns figures (fit, boots) for the author's own
    assertions."""
    from magline.core.dut import DutBackend
    from magline.core.fit import FitOptions, FitRefused, fit_calibration

    cycle = power_cycle or _power_cycle
    dut = open_dut()
    missing = [m for m in ("connect", "prepare", "samples", "calibration_params", "read_params", "write_params",
                           "commit", "reboot", "release_link", "await_boot", "selected_sensor_present",
                           "persistence_problems", "restore", "close") if not callable(getattr(dut, m, None))]
    assert not missing and isinstance(dut, DutBackend), f"the backend lacks {missing} (see DutBackend)"
    figures: dict[str, Any] = {}
    try:
        info = dut.connect()
        assert info.selected_sensor in info.sensors, "UnitInfo.selected_sensor must be one of UnitInfo.sensors"
        assert info.autopilot and info.firmware, "UnitInfo names the autopilot and its firmware"
        assert info.soft_iron_model in ("full", "diagonal"), "UnitInfo.soft_iron_model is 'full' or 'diagonal'"
        original = dut.read_params(list(prepare_params))
        assert set(original) == set(prepare_params), f"read_params({list(prepare_params)}) returned {original}"
        uptime_of = dut.uptime_s if isinstance(dut, ReportsUptime) else None  # what acquisition.warm_up_s waits on
        if uptime_of is not None:
            figures["uptime_s"] = up = uptime_of()
            assert up is None or (isinstance(up, (int, float)) and up >= 0), (
                f"uptime_s() returned {up!r}: seconds since the autopilot booted, or None when it does not say")
        if info.magnetometers:
            assert info.selected_sensor in [m.device_id for m in info.magnetometers], (
                "UnitInfo.magnetometers must list the selected sensor")
            dut.use_magnetometers([m.device_id for m in info.magnetometers])
        dut.prepare()

        mag, t_ms, wall = _stream(dut, samples, rate_hz)
        figures |= _check_more_and_imu(info, t_ms, field_ut, accelerometer)
        span_s = (t_ms[-1] - t_ms[0]) / 1000.0
        assert wall >= 0.5 * span_s, (f"{samples} readings spanning {span_s:.1f} s of the device's clock arrived in "
                                      f"{wall:.1f} s: samples() must follow the sensor, not run ahead of it")
        try:
            fit = fit_calibration(mag, FitOptions(field_ut=field_ut, coverage_bins=40, model=info.soft_iron_model))
        except FitRefused as exc:
            raise AssertionError(f"the readings do not determine a calibration ({exc.message}): is the device "
                                 "being tumbled through all orientations?") from None
        ratio = fit.field_estimate_ut / field_ut
        assert 0.7 < ratio < 1.3, (f"the readings' sphere has a radius of {fit.field_estimate_ut:.3g} for a "
                                   f"{field_ut:g} µT field: readings must be in µT")
        if hard_iron_ut is not None:
            off = np.abs(fit.hard_iron_ut - np.asarray(hard_iron_ut, float))
            assert np.all(off < 4 * fit.hard_iron_sigma_ut + 1.0), (
                f"offset {fit.hard_iron_ut.round(2)} µT fitted from the readings, the device's is {hard_iron_ut}: "
                "readings must be raw (uncalibrated), in µT, on the sensor's axes")
        figures["fit"] = fit

        params = dut.calibration_params(fit)
        before = dut.read_params(list(params))
        echoed = dut.write_params(params)
        for name, value in params.items():
            assert name in echoed, f"write_params() must return the echo of {name}"
            if isinstance(value, float):
                assert np.float32(echoed[name]) == np.float32(value), (
                    f"{name}: wrote {value!r}, echoed {echoed[name]!r} — the echo is the float32 the device holds")
        cycle(dut)  # not committed
        after = dut.read_params(list(params))
        assert unsaved_writes in ("lost", "kept", "unspecified"), f"unsaved_writes={unsaved_writes!r}"
        if unsaved_writes == "kept":
            gone = [n for n, v in params.items() if not np.isclose(after.get(n, np.nan), v, rtol=1e-6, atol=1e-9)]
            assert not gone, f"{gone} did not survive a power cycle, but the firmware is said to save every write"
        elif unsaved_writes == "lost":
            kept = [n for n in params if n in before and not np.isclose(after.get(n, np.nan), before[n], rtol=1e-6)]
            assert not kept, f"{kept} survived a power cycle without commit(): commit() must be what saves"

        dut.prepare()
        dut.write_params(params)
        dut.commit()
        started = time.monotonic()
        boot = cycle(dut)
        since = time.monotonic() - started
        uptime = boot.get("uptime_at_reconnect_s")
        assert uptime is None or uptime < since, "await_boot() must prove a new boot (its uptime is shorter)"
        figures["boot"] = boot
        if uptime_of is not None:
            up = uptime_of()
            assert up is None or up <= time.monotonic() - started, (
                f"uptime_s() says {up:.1f} s up {time.monotonic() - started:.1f} s after the power cycle began: "
                "it must be the new boot's")
        assert dut.selected_sensor_present(), "the calibrated sensor must be present after the power cycle"
        back = dut.read_params(list(params))
        wrong = [n for n, v in params.items() if not np.isclose(back.get(n, np.nan), v, rtol=1e-6, atol=1e-9)]
        assert not wrong, f"{wrong} not read back after commit() and a power cycle"
        for capability, why in REQUIRED_DUT_CAPABILITIES.items():
            assert isinstance(dut, capability), f"declare {capability.__name__}'s method: {why}"
        output = dut.calibrated_field_ut(20)
        if output is not None:
            measured = float(np.median(np.linalg.norm(np.atleast_2d(output), axis=1)))
            figures["calibrated_field_ut"] = measured
            assert abs(measured / field_ut - 1) * 100 <= tolerance_pct, (
                f"the firmware's calibrated output reads {measured:.2f} µT in a {field_ut:g} µT field: "
                "calibration_params() has a wrong sign, unit or matrix convention")
        if isinstance(dut, ReadsCalibratedFields):  # optional: several sensors side by side
            several = dut.calibrated_fields_ut(20, [info.selected_sensor])
            assert set(several) == {info.selected_sensor}, (
                f"calibrated_fields_ut(20, [{info.selected_sensor}]) returned sensors {sorted(several)}: one entry "
                "per device id asked for")
            alone = several[info.selected_sensor]
            if output is not None and alone is not None:
                beside = float(np.median(np.linalg.norm(np.atleast_2d(alone), axis=1)))
                assert abs(beside / measured - 1) * 100 <= tolerance_pct, (
                    f"calibrated_fields_ut reads {beside:.2f} µT where calibrated_field_ut read {measured:.2f} µT: "
                    "they must read the same calibrated output")
        if isinstance(dut, ReadsRawAndCalibrated) and (both := dut.raw_and_calibrated_ut(20)) is not None:
            sensor = info.selected_sensor
            assert sensor in both.raw_ut and sensor in both.to_body, (
                f"raw_and_calibrated_ut returned raw readings of {sorted(both.raw_ut)} and rotations of "
                f"{sorted(both.to_body)}, not of the calibrated sensor {sensor}")
            made = fit.apply(both.raw_ut[sensor]) @ np.asarray(both.to_body[sensor], float).T
            apart = float(np.linalg.norm(np.mean(np.atleast_2d(both.calibrated_ut) - made, axis=0)))
            figures["applied_difference_ut"] = apart
            # an output less the firmware's own bias estimate (PX4's HIGHRES_IMU): the station's own allowance
            allowed = 0.5 + estimated_bias_allowance_ut(both, tolerance_pct, field_ut)
            assert apart < allowed, (
                f"the calibrated readings are {apart:.2f} µT from the fit applied to the raw readings returned "
                f"beside them and turned by to_body (allowed {allowed:.2f} µT): each raw row must be the reading its "
                "calibrated row was made from, both in µT, and to_body the rotation the firmware applies after its "
                "calibration")

        dut.restore()
        cycle(dut)
        now = dut.read_params(list(prepare_params))
        changed = {n: (now.get(n), v) for n, v in original.items() if not np.isclose(now.get(n, np.nan), v)}
        assert not changed, (f"after restore() and a power cycle {changed} (now, before prepare()): restore() "
                             "must undo prepare() in storage too, since commit() saved what prepare() changed")
    finally:
        dut.close()
    return figures


# --------------------------------------------------------------------------- field sources, power controls


def check_field_source(open_source: Callable[[], Any], expected_ut: float | None = None,
                       tolerance_ut: float = 0.05) -> float:
    """Run the field-source contract (:class:`magline.plugin.FieldSource`): a finite reference
    in µT (the Earth's 20–70 µT, a coil's up to 500), the same for consecutive units (within
    ``tolerance_ut``, and equal to ``expected_ut`` when given), ``finish_unit()`` safe after every unit
    and twice in a row, ``reference_is_ambient`` a bool when declared, ``close()``.  Returns the reference."""
    from magline.core.field import FieldSource

    source = open_source()
    assert isinstance(source, FieldSource), "a field source has reference_field_ut(), finish_unit() and close()"
    try:
        first = source.reference_field_ut()
        assert isinstance(first, float) and np.isfinite(first), f"reference_field_ut() is a float (got {first!r})"
        assert 1.0 < first < 500.0, f"reference_field_ut() = {first:g}: the field must be in µT"
        source.finish_unit()
        source.finish_unit()
        second = source.reference_field_ut()
        assert abs(second - first) <= tolerance_ut, f"consecutive units got {first:g} and {second:g} µT"
        if expected_ut is not None:
            assert abs(first - expected_ut) <= tolerance_ut, f"reference {first:g} µT, expected {expected_ut:g} µT"
        ambient = getattr(source, "reference_is_ambient", False)
        assert isinstance(ambient, bool), "reference_is_ambient is True or False"
        source.finish_unit()
    finally:
        source.close()
    return first


def check_power_control(open_power: Callable[[], Any], open_dut: Callable[[], Any]) -> dict:
    """Run the power-control contract (:class:`magline.plugin.PowerControl`) with a DUT:
    ``power_up()`` makes the unit reachable, ``cycle(dut)`` returns figures (numbers, and the
    ``method`` that proved the cycle) with the unit back on a new boot and answering,
    ``finish()`` twice is safe, ``close()``.  Returns the cycle's figures."""
    power = open_power()
    for name in ("power_up", "cycle", "finish", "close"):
        assert callable(getattr(power, name, None)), f"a power control has {name}()"
    assert isinstance(getattr(power, "method", None), str), "a power control names its method (``method``)"
    dut = open_dut()
    try:
        power.power_up()
        dut.connect()
        figures = dict(power.cycle(dut))
        method = figures.pop("method", power.method)
        assert isinstance(method, str) and method, "cycle() says which method proved the power cycle"
        assert all(isinstance(v, int | float) for v in figures.values()), f"cycle() figures are numbers: {figures}"
        uptime, since = figures.get("uptime_at_reconnect_s"), figures.get("time_to_heartbeat_s")
        if uptime is not None and since is not None:
            assert uptime < since, "the unit after cycle() must be on a new boot (its uptime is shorter)"
        assert dut.selected_sensor_present(), "after cycle() the unit answers and its sensor is there"
        power.finish()
        power.finish()
    finally:
        dut.close()
        power.close()
    return {"method": method, **figures}
