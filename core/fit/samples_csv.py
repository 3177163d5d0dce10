"""The raw-sample CSV format shared by `magline fit`, the results store and attachments.

Header required; ``mag_x_ut,mag_y_ut,mag_z_ut`` mandatory, ``t_ms`` and ``temp_c`` optional.
Every malformed input gets a message naming the file, the line and the column, because the
person reading it is an operator or quality engineer, not a developer.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

REQUIRED = ("mag_x_ut", "mag_y_ut", "mag_z_ut")
OPTIONAL = ("t_ms", "temp_c")
APPLIED = ("applied_x_ut", "applied_y_ut", "applied_z_ut")  # the known field a Helmholtz coil applied


class SampleFileError(ValueError):
    """A raw-sample file that cannot be used, with the place of the problem in the message."""


@dataclass
class RawSamples:
    mag_ut: NDArray
    t_ms: NDArray | None = None
    temp_c: NDArray | None = None
    applied_ut: NDArray | None = None  # per sample, when the field was applied (coil), not rotated

    def __len__(self) -> int:
        return len(self.mag_ut)


def read_samples(path: str | Path) -> RawSamples:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise SampleFileError(f"{path}: cannot read: {exc.strerror}") from exc
    return parse_samples(text, str(path))


def parse_samples(text: str, name: str = "<samples>") -> RawSamples:
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or not any(cell.strip() for cell in rows[0]):
        raise SampleFileError(f"{name}: empty file (expected a header with {', '.join(REQUIRED)})")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise SampleFileError(f"{name}:1: missing column(s) {', '.join(missing)} (header: {', '.join(header)})")
    if any(c in header for c in APPLIED) and not all(c in header for c in APPLIED):
        raise SampleFileError(f"{name}:1: give all of {', '.join(APPLIED)} or none")
    cols = [c for c in (*REQUIRED, *OPTIONAL, *APPLIED) if c in header]
    index = {c: header.index(c) for c in cols}
    data: dict[str, list[float]] = {c: [] for c in cols}
    for lineno, row in enumerate(rows[1:], start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        for col in cols:
            i = index[col]
            cell = row[i].strip() if i < len(row) else ""
            try:
                value = float(cell)
            except ValueError:
                raise SampleFileError(f"{name}:{lineno}: column {col}: {cell!r} is not a number") from None
            if math.isnan(value) or math.isinf(value):
                raise SampleFileError(f"{name}:{lineno}: column {col}: {cell!r} is not a finite number")
            data[col].append(value)
    if not data[REQUIRED[0]]:
        raise SampleFileError(f"{name}: no samples after the header")
    mag = np.column_stack([data[c] for c in REQUIRED])
    return RawSamples(mag_ut=mag,
                      t_ms=np.asarray(data["t_ms"]) if "t_ms" in data else None,
                      temp_c=np.asarray(data["temp_c"]) if "temp_c" in data else None,
                      applied_ut=np.column_stack([data[c] for c in APPLIED]) if APPLIED[0] in data else None)


def format_samples(samples: RawSamples) -> str:
    """CSV text for samples (the inverse of :func:`parse_samples`)."""
    out = io.StringIO()
    cols = list(REQUIRED)
    extra = [("t_ms", samples.t_ms), ("temp_c", samples.temp_c)]
    cols += [name for name, values in extra if values is not None]
    if samples.applied_ut is not None:
        cols += list(APPLIED)
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(cols)
    for i in range(len(samples)):
        row = [f"{v:.4f}" for v in samples.mag_ut[i]]
        row += [f"{values[i]:.3f}" for _, values in extra if values is not None]
        if samples.applied_ut is not None:
            row += [f"{v:.4f}" for v in samples.applied_ut[i]]
        writer.writerow(row)
    return out.getvalue()


EXPORT_KEYS = ("run_uuid", "serial", "attempt", "accepted")  # what ``magline export --raw`` adds per row


def select_export_rows(text: str, name: str, run: str | None = None, serial: str | None = None,
                       attempt: int | None = None, with_refused: bool = False,
                       sensor: str | None = None) -> tuple[str, str]:
    """One run's readings out of a ``magline export --raw`` file, as CSV text, and what was chosen.

    Why: an export holds every run of every serial and every attempt, the refused ones too; pooled,
    two units' readings fit no ellipsoid, and the fit's advice ("keep magnets away") is a physical
    diagnosis of a file problem.  A file without the export's columns is returned as it is."""
    rows = list(csv.reader(io.StringIO(text)))
    header = [h.strip() for h in rows[0]] if rows else []
    if not all(k in header for k in EXPORT_KEYS):
        if run or serial or attempt is not None:
            raise SampleFileError(f"{name}: --run, --serial and --attempt choose from a magline export --raw file "
                                  f"(columns {', '.join(EXPORT_KEYS)}); this file has {', '.join(header)}")
        return text, ""
    col = {k: header.index(k) for k in EXPORT_KEYS}
    body = [r for r in rows[1:] if r and any(c.strip() for c in r)]
    if "sensor" in header:  # every magnetometer of the unit is in the file: one is fitted (the primary by default)
        at = header.index("sensor")
        present = sorted({r[at].strip() for r in body})
        wanted = (sensor or "mag1").strip()
        if wanted not in present:
            raise SampleFileError(f"{name}: no readings of sensor {wanted!r} (the file has {', '.join(present)})")
        body = [r for r in body if r[at].strip() == wanted]
    elif sensor not in (None, "mag1"):
        raise SampleFileError(f"{name}: --sensor chooses from a magline export --raw file with a sensor column")
    if run:
        body = [r for r in body if r[col["run_uuid"]].startswith(run.strip())]
    if serial:
        exact = [r for r in body if r[col["serial"]].strip() == serial.strip()]
        body = exact or [r for r in body if r[col["serial"]].strip().upper() == serial.strip().upper()]
    if attempt is not None:
        body = [r for r in body if r[col["attempt"]].strip() == str(attempt)]
    elif not with_refused:
        body = [r for r in body if r[col["accepted"]].strip() == "1"]
    runs = {}
    for r in body:
        runs.setdefault(r[col["run_uuid"]], (r[col["serial"]], set()))[1].add(r[col["attempt"]])
    if not runs:
        raise SampleFileError(f"{name}: no readings match (an accepted attempt unless --attempt or --with-refused; "
                              "see the file's run_uuid, serial and attempt columns)")
    if len(runs) > 1:
        listed = "; ".join(f"{u[:8]} {sn} attempt {', '.join(sorted(a))}" for u, (sn, a) in list(runs.items())[:12])
        raise SampleFileError(f"{name}: {len(runs)} runs in the file — choose one with --run UUID (its first "
                              f"characters) or --serial SN: {listed}{' …' if len(runs) > 12 else ''}")
    (uuid, (sn, chosen)), = runs.items()
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows([header, *body])
    which = f" sensor {(sensor or 'mag1').strip()}" if "sensor" in header else ""
    return out.getvalue(), f"run {uuid[:8]} serial {sn} attempt {', '.join(sorted(chosen))}{which}"
