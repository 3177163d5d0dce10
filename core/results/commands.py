"""``magline show`` and ``magline export``: a whole record, and filtered exports that stream.

Both read the station's results store through its engine, so they work the same on the embedded
SQLite file and on a shared server.
"""

from __future__ import annotations

import csv
import json
import sys
from typing import TYPE_CHECKING, Any, TextIO

from magline.core.faults import StationFault
from magline.core.measurements import base_name
from magline.core.results.contract import ReadsInSql
from magline.core.results.reading import (
    NUMERIC_NAMES,
    RUN_COLUMNS,
    RunNotFound,
    attempt_sensor_streams,
    export_runs,
    find_run_or_serial,
    measurement_names,
    run_attempts,
)
from magline.core.results.record_words import (
    compass_rows,
    interference_rows,
    mounting_rows,
    persistence_rows,
    unit_facts,
    value_words,
)
from magline.core.text import FLOAT32_RULE, fmt, param_text, seconds, stop_line

if TYPE_CHECKING:
    from magline.core.results.reading import RunFilter


def engine_of(store: Any) -> Any:
    if not isinstance(store, ReadsInSql):
        raise StationFault("this station's results sink is not a SQL store: show and export read SQL stores only")
    return store.engine


def show(store: Any, run: str, as_json: bool, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    with engine_of(store).connect() as conn:
        record = find_run_or_serial(conn, run)
    if record is None:
        print(RunNotFound(run, store.where), file=sys.stderr)
        return 1
    if as_json:
        out.write(json.dumps(record, default=str) + "\n")
        return 0
    lines = [f"run {record['id']} ({record['run_uuid']}) in {store.where}",
             f"unit {record['serial']}  part {record['part']}  station {record['station_id']}  line {record['line']}",
             f"operator {record['operator'] or '—'}  magline {record['software_version']}  "
             f"limits {record['limit_hash']}",
             f"{record['started']} → {record['finished'] or '—'}  {str(record['verdict']).upper()}"
             + (f": {record['cause']}" if record["cause"] else "")]
    unit = record.get("unit_info") or {}
    if unit:
        lines.append("unit: " + "; ".join(f"{name} {words}" for name, words in unit_facts(unit)))
    compasses = compass_rows(unit)
    if compasses:
        lines.append("magnetometers:")
        lines += [f"  {name:<5} {label}, device id {device}, orientation {orientation}"
                  for name, label, device, orientation in compasses]
    mounting = mounting_rows(unit)
    if mounting:
        lines.append("mounting:")
        lines += [f"  {name:<10} {found}" + (f", {distance}" if distance else "")
                  + (f", inclination {incl}" if incl else "") for name, found, distance, incl in mounting]
    interference = interference_rows(unit)
    if interference:
        sweep = unit["interference"]
        lines.append(f"current interference (swept to {sweep['current_max_a']:g} A in {sweep['seconds']:.0f} s"
                     + (f", {sweep['readings_per_step']} readings a step" if sweep.get("readings_per_step") else "")
                     + (f" from a {sweep['stream_hz']:g} Hz stream" if sweep.get("stream_hz") else "")
                     + (f", {sweep['held_readings']} more held at the top and the last 0 A together"
                        if sweep.get("held_readings") else "")
                     + (f", the unit's current sensor {sweep['sensor_error_pct']:+.1f} % against the load"
                        if sweep.get("sensor_error_pct") is not None else "") + "):")
        lines += [f"  {name}: " + ", ".join(w for w in words if w) for name, *words in interference]
    lines.append("phases:")
    lines += [f"  {p['name']:<12} {str(p['outcome']).upper():<8} {seconds(p['duration_s'] or 0.0):>7}"
              + (f"  {p['message']}" if p["message"] else "") for p in record["phases"]]
    lines.append("attempts:")
    lines += [f"  {a['attempt']}: " + ("accepted" if a["accepted"] else f"not used ({a['refused'] or 'superseded'})")
              + f" — {a['samples']} readings, coverage {a['coverage']:.0%}"
              + (f", {a['repeats']} repeats dropped" if a.get("repeats") else "")
              + (f", {_stopped(a)}" if a.get("stopped") else "")
              for a in record["attempts"]]
    lines.append("measurements:")
    for m in record["measurements"]:
        if m["kind"] == "numeric":
            lines.append(f"  {m['name']:<24} {fmt(m['value'], m['unit'] or ''):>14}  "
                         f"[{fmt(m['low'])}, {fmt(m['high'])}]  {m['verdict']}")
    lines.append(f"station file {record.get('station_hash') or '—'}, reference field "
                 f"{fmt(record.get('reference_field_ut'), 'µT')}")
    if any(record["params"].get(stage) for stage in ("before", "written", "echoed", "read_back")):
        lines.append(f"params ({FLOAT32_RULE}):")
    for stage in ("before", "written", "echoed", "read_back"):
        values = record["params"].get(stage)
        if values:
            lines.append(f"  {stage}: " + ", ".join(f"{k}={param_text(v)}" for k, v in sorted(values.items())))
    if record.get("persistence"):
        lines.append("persistence: " + "; ".join(f"{name} {words}" for name, words in
                                                 persistence_rows(_rounded(record["persistence"]))))
    for key, title in (("left_changed", "NOT RESTORED"), ("unverified_params", "UNVERIFIED")):
        if record.get(key):
            lines.append(f"{title}: {value_words(record[key])} — re-test the unit")
    out.write("\n".join(lines) + "\n")
    return 0


def _rounded(value: Any) -> Any:
    """A stored JSON value with its floats at 4 significant digits, for reading (the record keeps them whole)."""
    if isinstance(value, float):
        return float(f"{value:.4g}")
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


def _stopped(attempt: dict) -> str:
    """Why and when the attempt's tumble ended, with the running fit's predicted heading σ."""
    line = stop_line(attempt["stopped"], attempt.get("tumble_s") or 0.0, attempt["samples"]).split(" — ")[0]
    predicted = json.loads(attempt["predicted"]) if attempt.get("predicted") else {}
    worst = max((f.get("direction_sigma_deg", 0.0) for f in predicted.values()), default=None)
    return line + (f", predicted heading σ {worst:.2f}°" if worst is not None else "")


def export(store: Any, where: RunFilter, fmt_name: str, raw: bool, out: TextIO | None = None) -> int:
    """Stream matching runs as CSV (a row per run, or per raw sample with ``raw``) or JSON lines."""
    out = out or sys.stdout
    count = 0
    with engine_of(store).connect() as conn:
        if fmt_name == "jsonl":
            for run in export_runs(conn, where):
                if raw:
                    run["attempts"] = [_raw_attempt(a) for a in run_attempts(conn, run["id"], with_samples=True)]
                out.write(json.dumps(run, default=str) + "\n")
                count += 1
            return _done(count)
        writer = csv.writer(out, lineterminator="\n")
        if raw:  # every magnetometer's readings: the primary is "mag1", the others named as in the measurements
            writer.writerow(["run_uuid", "serial", "attempt", "accepted", "sensor", "mag_x_ut", "mag_y_ut", "mag_z_ut",
                             "t_ms"])
            for run in export_runs(conn, where):
                names = _sensor_names(run.get("calibration"))
                for a in run_attempts(conn, run["id"], with_samples=True):
                    streams = [("mag1", a["raw"])] + [
                        (names.get(device_id, f"mag:{device_id}"), samples)
                        for device_id, samples in attempt_sensor_streams(conn, run["id"], a["attempt"]).items()]
                    for sensor, samples in streams:
                        for i in range(len(samples) if samples is not None else 0):
                            t = samples.t_ms[i] if samples.t_ms is not None and len(samples.t_ms) else ""
                            writer.writerow([run["run_uuid"], run["serial"], a["attempt"], a["accepted"], sensor,
                                             *samples.mag_ut[i].tolist(), t])
                count += 1
            return _done(count)
        held = measurement_names(conn, where)
        sensors = ["mag1", *(p for p in ("mag2", "mag3") if any(n.startswith(f"{p}.") for n in held))]
        names = [n for n in NUMERIC_NAMES if _sensor_of(n) in sensors and (not _only_where_held(n) or n in held)]
        names += sorted(held - set(NUMERIC_NAMES))  # the plugins' own measurements, after magline's
        writer.writerow([*RUN_COLUMNS, "test", *names, *(f"{p}.{c}" if p != "mag1" else c for p in sensors
                                                          for c in SOFT_IRON_COLUMNS),
                         "failed", "review", "params_written"])
        for run in export_runs(conn, where, with_params=True):
            m = run["measurements"]
            failed = ";".join(sorted(k for k, v in m.items() if v["verdict"] == "fail"))
            review = ";".join(sorted(f.get("name", "") for f in run.get("review") or [] if isinstance(f, dict)))
            written = ";".join(f"{k}={_cell(v)}" for k, v in sorted(run.get("params_written", {}).items()))
            writer.writerow([_cell(run[c]) for c in RUN_COLUMNS] + [_test(run)]
                            + [_cell(m.get(n, {}).get("value")) for n in names]
                            + [c for p in sensors for c in _soft_iron(run.get("calibration"), p)]
                            + [failed, review, written])
            count += 1
    return _done(count)


def _sensor_of(name: str) -> str:
    """Which compass a measurement column belongs to ("mag1" the primary; a pair: its second)."""
    head = name.split(".")[0] if "." in name and name.split(".")[0].startswith("mag") else "mag1"
    return head.split("-")[-1]


def _test(run: dict) -> str:
    """First test of the serial, or which re-test (the record counts the runs before it)."""
    earlier = run.get("earlier_runs") or 0
    return "first" if earlier == 0 else f"re-test {earlier}"


def _cell(value: Any) -> Any:
    """A CSV cell: integers as integers (2, not 2.0), nothing as empty."""
    if value is None:
        return ""
    if isinstance(value, float) and value.is_integer() and abs(value) < 2**53:
        return int(value)
    return value


def _sensor_names(calibration: Any) -> dict[int, str]:
    """Device id → the name a further magnetometer has in the measurements (``mag2``…), from the record."""
    sensors = calibration.get("magnetometers") if isinstance(calibration, dict) else None
    return {int(v["device_id"]): k for k, v in (sensors or {}).items() if isinstance(v, dict) and "device_id" in v}


# the soft-iron matrix written to the unit (the primary's), one named column per element
SOFT_IRON_COLUMNS = tuple(f"soft_iron_{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3))


def _only_where_held(name: str) -> bool:
    """Columns a station has only where its units have them: a pair's (two compasses), the current
    interference's (products that sweep) — not a block of empty columns on every other export."""
    base = base_name(name)
    return "-" in name.split(".")[0] or base.startswith("interference_") or base == "current_sensor_error_pct"


def _soft_iron(calibration: Any, sensor: str = "mag1") -> list[Any]:
    """The soft-iron matrix written for ``sensor`` (the primary's at the top of the calibration, the
    others' under ``magnetometers``), row by row; empty cells where the run has none."""
    own = calibration if sensor == "mag1" else (calibration or {}).get("magnetometers", {}).get(sensor)
    matrix = own.get("soft_iron") if isinstance(own, dict) else None
    return [_cell(v) for row in matrix for v in row] if matrix else [""] * len(SOFT_IRON_COLUMNS)


def _raw_attempt(attempt: dict) -> dict:
    samples = attempt.pop("raw")
    if samples is not None:
        attempt["raw"] = {"mag_ut": samples.mag_ut.tolist(),
                          "t_ms": samples.t_ms.tolist() if samples.t_ms is not None else None}
    return attempt


def _done(count: int) -> int:
    print(f"{count} run{'s' if count != 1 else ''} exported", file=sys.stderr)
    return 0
