"""The ACME board as a magline DUT backend (see ``magline.core.dut.DutBackend`` and docs/plugins.md).

Units at the boundary: the board speaks milligauss and *adds* its offsets; magline speaks µT and
subtracts (``m_cal = S·(m_raw − h)``).  The conversion lives in :meth:`AcmeDut.calibration_params`
and is proven by the board's own calibrated output after the power cycle (``calibrated_field_ut``).
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Iterator
from typing import Annotated

import numpy as np
from magline.plugin import DutError, ImuSeries, LinkError, NotRestored, SampleChunk, UnitInfo, await_new_boot
from pydantic import BaseModel, ConfigDict, Field

from acme_magline.protocol import MATRIX, UT_PER_MG

CHUNK = 10
MSS_PER_MG = 9.80665 / 1000.0


class AcmeOptions(BaseModel):
    """``products.<part>.options`` of an ACME part, checked by ``magline check``."""

    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    connect_timeout_s: Annotated[float, Field(gt=0)] = 3.0
    """The board answers within this, else the unit is an ERROR in connect."""
    boot_timeout_s: Annotated[float, Field(gt=0)] = 10.0
    """A reboot → the new boot answers."""
    reply_timeout_s: Annotated[float, Field(gt=0)] = 2.0
    """One request's reply."""


class AcmeDut:
    def __init__(self, options: AcmeOptions, connection: str) -> None:
        scheme, _, address = connection.partition(":")
        host, _, port = address.rpartition(":")
        if scheme != "tcp" or not port.isdigit():
            raise ValueError(f"ACME boards are reached as tcp:HOST:PORT (got {connection!r})")
        self.opts, self.address = options, (host, int(port))
        self.sock: socket.socket | None = None
        self.wire = None
        self.device_id = 0
        self._saved_autocal: float | None = None
        self.boot_timeout_s = options.boot_timeout_s

    # ------------------------------------------------------------------ link
    def _open(self, timeout_s: float) -> None:
        try:
            self.sock = socket.create_connection(self.address, timeout=timeout_s)
        except OSError as exc:
            raise LinkError(f"ACME board at {self.address[0]}:{self.address[1]} does not answer: {exc}") from None
        self.sock.settimeout(self.opts.reply_timeout_s)
        self.wire = self.sock.makefile("rw", encoding="ascii", newline="\n")

    def _send(self, line: str) -> None:
        if self.wire is None:
            raise LinkError("the link to the ACME board is closed")
        try:
            self.wire.write(line + "\n")
            self.wire.flush()
        except OSError as exc:
            raise LinkError(f"link to the ACME board lost: {exc}") from None

    def _line(self) -> str:
        try:
            line = self.wire.readline()
        except OSError as exc:  # timeout or reset
            raise LinkError(f"no answer from the ACME board: {exc}") from None
        if not line:
            raise LinkError("the ACME board closed the link")
        return line.strip()

    def _ask(self, line: str, expect: str) -> list[str]:
        self._send(line)
        while True:
            parts = self._line().split()
            if parts and parts[0] == "ERR":
                raise DutError(f"ACME board refused {line!r}: {' '.join(parts[1:])}")
            if parts and parts[0] == expect:
                return parts[1:]

    def _identify(self, timeout_s: float) -> list[str]:
        """Open the link and ask who answers, retrying until ``timeout_s``: a board that is still
        booting accepts the connection and drops it."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.release_link()
                self._open(max(min(self.opts.connect_timeout_s, deadline - time.monotonic()), 0.1))
                return self._ask("ID?", "ID")
            except DutError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)

    def connect(self) -> UnitInfo:
        model, firmware, device = self._identify(self.opts.connect_timeout_s)
        self.device_id = int(device, 16)
        return UnitInfo(autopilot=model, firmware=firmware, sensors=[self.device_id], selected_sensor=self.device_id,
                        soft_iron_model="full")

    def close(self) -> None:
        self.release_link()

    def release_link(self) -> None:
        if self.sock is not None:
            self.sock.close()
        self.sock = self.wire = None

    # ------------------------------------------------------------------ prepare / restore
    def prepare(self) -> None:
        autocal = self.read_params(["AUTOCAL"])["AUTOCAL"]
        if self._saved_autocal is None:
            self._saved_autocal = autocal
        if autocal:
            self.write_params({"AUTOCAL": 0.0})

    def restore(self) -> None:
        """AUTOCAL back in RAM *and* flash: the calibration's SAVE stored it switched off."""
        if self._saved_autocal is None:
            return
        try:
            if self.wire is None:
                self._open(self.opts.connect_timeout_s)
            self.write_params({"AUTOCAL": self._saved_autocal})
            self.commit()
        except DutError as exc:
            raise NotRestored(str(exc), {"AUTOCAL": f"0 (was {self._saved_autocal:g})"}) from exc
        self._saved_autocal = None

    # ------------------------------------------------------------------ data
    def samples(self, rate_hz: float) -> Iterator[SampleChunk]:
        """Readings as the board sends them (it paces the stream to its sensor), µT."""
        self._send(f"STREAM {rate_hz:g}")
        try:
            while True:
                rows = []
                while len(rows) < CHUNK:
                    parts = self._line().split()
                    if parts and parts[0] == "M":
                        rows.append([float(v) for v in parts[1:8]])
                block = np.array(rows)
                # the accelerometer beside the magnetometer: the station proves the sensor's mounting with it
                imu = ImuSeries(t_ms=block[:, 0], accel_mss=block[:, 4:7] * MSS_PER_MG)
                yield SampleChunk(mag_ut=block[:, 1:4] * UT_PER_MG, t_ms=block[:, 0], imu=imu)
        finally:
            if self.wire is not None:
                with contextlib.suppress(DutError):  # the link is gone: nothing left streaming
                    self._ask("STOP", "OK")

    def board_temp_c(self) -> float:
        """The board's own temperature (``TEMP?``): the plugin's own measurement, ``acme_board_temp_c``."""
        return float(self._ask("TEMP?", "TEMP")[0])

    def calibrated_field_ut(self, count: int) -> np.ndarray:
        return np.array([[float(v) for v in self._ask("CAL?", "C")] for _ in range(count)]) * UT_PER_MG

    # ------------------------------------------------------------------ parameters
    def calibration_params(self, fit) -> dict[str, float]:
        params = {f"OFS_{axis}": -float(h) / UT_PER_MG for axis, h in zip("XYZ", fit.hard_iron_ut, strict=True)}
        params.update({name: float(fit.soft_iron[i, j]) for name, i, j in MATRIX})
        return params

    def read_params(self, names: list[str]) -> dict[str, float]:
        return {name: float(self._ask(f"GET {name}", "VAL")[1]) for name in names}

    def write_params(self, params: dict[str, float]) -> dict[str, float]:
        return {name: float(self._ask(f"SET {name} {value!r}", "VAL")[1]) for name, value in params.items()}

    def commit(self) -> None:
        self._ask("SAVE", "OK")

    # ------------------------------------------------------------------ power cycle
    def reboot(self) -> None:
        self._ask("REBOOT", "OK")
        self.release_link()

    def await_boot(self, since: float) -> dict[str, float]:
        def reconnect(remaining_s: float) -> None:
            self._identify(remaining_s)  # keeps trying: await_new_boot stops at the first error

        def uptime() -> float:
            return float(self._ask("UPTIME?", "UPTIME")[0])

        reconnected, up = await_new_boot(reconnect, uptime, since, self.opts.boot_timeout_s)
        return {"time_to_heartbeat_s": reconnected, "uptime_at_reconnect_s": up}

    def selected_sensor_present(self) -> bool:
        return int(self._ask("ID?", "ID")[2], 16) == self.device_id

    def persistence_problems(self) -> list[str]:
        return []
