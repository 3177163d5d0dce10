"""A SCPI instrument session over VISA (pyvisa + the pure-Python pyvisa-py backend).

Why here: bench supplies (power control), DMMs reading a fluxgate and Helmholtz current sources
(field sources) all speak SCPI; each plugin opens its instrument through this one helper, which
adds what every factory use needs — a timeout, the resource named in every error, and a check of
the instrument's error queue (``SYST:ERR?``) after each step, because an instrument that refuses
a setting says so only there.
"""

from __future__ import annotations

from typing import Any

from magline.core.faults import StationFault


class InstrumentError(StationFault):
    """The instrument is unreachable, silent, or reported an error in its queue."""


class ScpiInstrument:
    """``TCPIP0::host::port::SOCKET`` or ``ASRL/dev/ttyUSB0::INSTR`` (serial) resources."""

    def __init__(self, resource: str, timeout_s: float = 2.0) -> None:
        import pyvisa  # imported on use: stations without instruments do not need it

        self.resource = resource
        try:
            self._rm = pyvisa.ResourceManager("@py")
            self._inst: Any = self._rm.open_resource(resource, read_termination="\n", write_termination="\n",
                                                     timeout=int(timeout_s * 1000))
        except Exception as exc:  # pyvisa raises several types (VisaIOError, ValueError, OSError)
            raise InstrumentError(f"cannot open instrument {resource}: {exc}") from exc

    def write(self, command: str) -> None:
        try:
            self._inst.write(command)
        except Exception as exc:
            raise InstrumentError(f"{self.resource}: writing {command!r} failed: {exc}") from exc

    def query(self, command: str) -> str:
        try:
            return str(self._inst.query(command)).strip()
        except Exception as exc:
            raise InstrumentError(f"{self.resource}: no answer to {command!r}: {exc}") from exc

    def query_float(self, command: str) -> float:
        answer = self.query(command)
        try:
            return float(answer)
        except ValueError:
            raise InstrumentError(f"{self.resource}: {command!r} answered {answer!r}, not a number") from None

    def errors(self) -> list[str]:
        """Drain the error queue (``SYST:ERR?`` until ``0,...``)."""
        found = []
        for _ in range(20):
            answer = self.query("SYST:ERR?")
            code = answer.split(",", 1)[0].strip()
            if code in ("0", "+0"):
                break
            found.append(answer)
        return found

    def check(self, step: str) -> None:
        """Raise when the instrument reported any error during ``step``."""
        errors = self.errors()
        if errors:
            raise InstrumentError(f"{self.resource} reported during {step}: {'; '.join(errors)}")

    def close(self) -> None:
        try:
            self._inst.close()
            self._rm.close()
        except Exception:  # closing a dead session must not hide the error that killed it
            pass
