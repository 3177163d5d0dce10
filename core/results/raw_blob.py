"""Raw samples as a compact binary blob: one NumPy ``.npy`` structured array per attempt.

Why this format (figures in ``benchmarks/results_store.py --raw-formats``): 600 samples take
about 27 kB as CSV text and 14 kB as float32 columns (``t_ms`` float64), and compression wins
little on sensor noise while it costs time on every read.  ``.npy`` is NumPy's own documented
format: the header names every column (the CSV names, so the store and ``magline fit`` files speak
the same words) and its type, so any Python with NumPy reads a blob without magline.

Precision: float32 keeps 24 bits of mantissa, 0.00002 µT at 200 µT — far below any sensor's
resolution (0.1 µT for ArduPilot's milligauss integers).  Time is float64: milliseconds since the
start of the acquisition stay exact to the microsecond over days.
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np

from magline.core.fit.samples_csv import APPLIED, OPTIONAL, REQUIRED, RawSamples

MAGIC = b"\x93NUMPY"  # every .npy file starts with it; a blob without it is not ours


class RawBlobError(ValueError):
    """A stored blob that is not a raw-sample array."""


def encode(samples: RawSamples) -> bytes:
    columns: list[tuple[str, str, np.ndarray]] = [
        (name, "<f4", samples.mag_ut[:, i]) for i, name in enumerate(REQUIRED)]
    if samples.t_ms is not None:
        columns.append(("t_ms", "<f8", samples.t_ms))
    if samples.temp_c is not None:
        columns.append(("temp_c", "<f4", samples.temp_c))
    if samples.applied_ut is not None:
        columns += [(name, "<f4", samples.applied_ut[:, i]) for i, name in enumerate(APPLIED)]
    return _npy(columns)


def _npy(columns: list[tuple[str, str, np.ndarray]]) -> bytes:
    """Named columns as one structured ``.npy`` array."""
    table = np.empty(len(columns[0][2]), dtype=[(name, dtype) for name, dtype, _ in columns])
    for name, _, values in columns:
        table[name] = values
    out = io.BytesIO()
    np.lib.format.write_array(out, table, allow_pickle=False)
    return out.getvalue()


def decode(blob: bytes) -> RawSamples:
    if not blob.startswith(MAGIC):
        raise RawBlobError("not a raw-sample array (no .npy header)")
    table = np.lib.format.read_array(io.BytesIO(blob), allow_pickle=False)
    names = table.dtype.names or ()
    missing = [c for c in REQUIRED if c not in names]
    if missing:
        raise RawBlobError(f"raw-sample array without column(s) {', '.join(missing)}")

    def column(name: str) -> np.ndarray | None:
        return _widen(table[name]) if name in names else None

    return RawSamples(
        mag_ut=np.column_stack([_widen(table[c]) for c in REQUIRED]),
        t_ms=column(OPTIONAL[0]), temp_c=column(OPTIONAL[1]),
        applied_ut=np.column_stack([_widen(table[c]) for c in APPLIED]) if APPLIED[0] in names else None)


def _widen(values: np.ndarray) -> np.ndarray:
    """float64 of the shortest decimal that is the stored float32 (12.3, not 12.300000190734863):
    exports and reports then show the numbers the sensor gave."""
    if values.dtype == np.float32:
        return values.astype(str).astype(np.float64)
    return values.astype(np.float64)


IMU_COLUMNS = ("acc_x_mss", "acc_y_mss", "acc_z_mss")
GYRO_COLUMNS = ("gyro_x_rads", "gyro_y_rads", "gyro_z_rads")


def encode_imu(imu: Any) -> bytes:
    """The accelerometer (and gyro) readings of an attempt: ``t_ms`` float64, the rest float32."""
    columns: list[tuple[str, str, np.ndarray]] = [("t_ms", "<f8", np.asarray(imu.t_ms, float))]
    columns += [(name, "<f4", np.asarray(imu.accel_mss, float)[:, i]) for i, name in enumerate(IMU_COLUMNS)]
    if imu.gyro_rads is not None:
        columns += [(name, "<f4", np.asarray(imu.gyro_rads, float)[:, i]) for i, name in enumerate(GYRO_COLUMNS)]
    return _npy(columns)


def decode_imu(blob: bytes) -> Any:
    from magline.core.mounting import ImuSeries

    if not blob.startswith(MAGIC):
        raise RawBlobError("not an IMU array (no .npy header)")
    table = np.lib.format.read_array(io.BytesIO(blob), allow_pickle=False)
    names = table.dtype.names or ()
    if "t_ms" not in names or any(c not in names for c in IMU_COLUMNS):
        raise RawBlobError(f"IMU array without column(s) t_ms, {', '.join(IMU_COLUMNS)}")
    gyro = np.column_stack([_widen(table[c]) for c in GYRO_COLUMNS]) if GYRO_COLUMNS[0] in names else None
    return ImuSeries(t_ms=_widen(table["t_ms"]), accel_mss=np.column_stack([_widen(table[c]) for c in IMU_COLUMNS]),
                     gyro_rads=gyro)
