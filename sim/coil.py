"""A simulated 3-axis Helmholtz coil driven by a three-channel current source over SCPI.

Physics: the field at the centre is ``K·I + ambient + drift`` (µT), with ``K`` the coil constants
(µT/A per axis), the ambient (Earth) field the station must null, and a warm-up drift of the coil
constants after the output goes on (copper heats, the constant falls by ``warmup_drop`` with time
constant ``warmup_tau_s``).  ``SIM:FIELD?`` returns that true field — a simulation-only channel
standing in for what a DUT and a fluxgate physically sense at the centre.

SCPI: ``SOURn:CURR <A>`` / ``SOURn:CURR?``, ``MEASn:CURR?`` (n = 1..3), ``OUTP ON|OFF``,
``OUTP?``, ``*RST``, plus ``*IDN?``, ``*CLS``, ``SYST:ERR?``.  Faults: ``output_off`` (the output
never switches on: currents read back 0), ``over_current`` (a shorted turn: a current above 30 % of the
maximum trips the output off with an error), ``scpi_error`` (every setting leaves an error in the queue),
``silent`` (no answers).
"""

from __future__ import annotations

import time

import numpy as np
from numpy.typing import NDArray

from magline.sim.scpi_server import ScpiServer

FAULTS = ("output_off", "over_current", "scpi_error", "silent")


class CoilSim(ScpiServer):
    identity = "magline,SIM-COIL-3CH,0001,1.0"

    def __init__(self, listen: str = "tcp:127.0.0.1:5026", constants_ut_per_a: tuple[float, float, float] = (
            100.0, 102.0, 98.5), ambient_ut: tuple[float, float, float] = (21.5, 1.4, 43.3),
                 max_current_a: float = 1.5, warmup_drop: float = 0.002, warmup_tau_s: float = 5.0,
                 noise_ut: float = 0.0, fault: str | None = None, seed: int | None = None) -> None:
        if fault is not None and fault not in FAULTS:
            raise ValueError(f"unknown coil fault {fault!r}; choose from {', '.join(FAULTS)}")
        super().__init__(listen)
        self.constants = np.asarray(constants_ut_per_a, float)
        self.ambient = np.asarray(ambient_ut, float)
        self.max_current_a = max_current_a
        self.warmup_drop = warmup_drop
        self.warmup_tau_s = warmup_tau_s
        self.noise_ut = noise_ut
        self.fault = fault
        self.silent = fault == "silent"
        self.rng = np.random.default_rng(seed)
        self.current = np.zeros(3)
        self.output = False
        self.on_since: float | None = None

    # ------------------------------------------------------------------ physics
    def driven_current(self) -> NDArray:
        return self.current if self.output and self.fault != "output_off" else np.zeros(3)

    def true_field_ut(self) -> NDArray:
        with self.lock:
            k = self.constants.copy()
            if self.on_since is not None:
                k *= 1.0 - self.warmup_drop * (1.0 - np.exp(-(time.monotonic() - self.on_since) / self.warmup_tau_s))
            field = k * self.driven_current() + self.ambient
        return field + self.rng.normal(scale=self.noise_ut, size=3) if self.noise_ut else field

    # ------------------------------------------------------------------ SCPI
    def command(self, head: str, arg: str) -> str | None:
        if head == "SIM:FIELD?":
            return ",".join(f"{v:.6f}" for v in self.true_field_ut())
        if head == "*RST":
            self.current[:] = 0.0
            self._output(False)
            return None
        if head in ("OUTP?", "OUTPUT?"):
            return "1" if self.output else "0"
        if head in ("OUTP", "OUTPUT"):
            state = arg.upper()
            if state not in ("ON", "OFF", "1", "0"):
                self.errors.append('-224,"Illegal parameter value"')
                return None
            self._output(state in ("ON", "1"))
            return None
        channel, kind = self._channel(head)
        if kind == "SET":
            value = float(arg)
            if abs(value) > self.max_current_a:
                self.errors.append(f'-222,"Data out of range; channel {channel + 1} {value:g} A exceeds '
                                   f'{self.max_current_a:g} A"')
                return None
            if self.fault == "over_current" and abs(value) > 0.3 * self.max_current_a:
                self._output(False)  # a shorted turn: the channel's protection trips
                self.errors.append(f'-310,"System error; over-current on channel {channel + 1}, output off"')
                return None
            self.current[channel] = value
            if self.fault == "scpi_error":
                self.errors.append('-350,"Queue overflow; simulated controller fault"')
            return None
        if kind == "QUERY":
            return f"{self.current[channel]:.5f}"
        return f"{self.driven_current()[channel]:.5f}"  # MEAS

    def _channel(self, head: str) -> tuple[int, str]:
        for prefix, kind in (("SOUR", "SET"), ("SOURCE", "SET"), ("MEAS", "MEAS"), ("MEASURE", "MEAS")):
            if head.startswith(prefix) and head[len(prefix):len(prefix) + 1] in "123" and len(head) > len(prefix):
                n = int(head[len(prefix)])
                rest = head[len(prefix) + 1:]
                if rest == ":CURR" and kind == "SET":
                    return n - 1, "SET"
                if rest == ":CURR?":
                    return n - 1, "QUERY" if kind == "SET" else "MEAS"
        raise KeyError(head)

    def _output(self, on: bool) -> None:
        if on and not self.output:
            self.on_since = time.monotonic()
        if not on:
            self.on_since = None
        self.output = on


class CoilChannelSim(ScpiServer):
    """One bipolar single-channel current source driving one axis of a :class:`CoilSim`
    (``CURR <A>``, ``CURR?``, ``MEAS:CURR?``, ``OUTP ON|OFF``, ``OUTP?``): for coils wired to three
    separate supplies instead of one controller.  The coil is passive here: its field on this
    axis follows this source's output."""

    identity = "magline,SIM-BIPOLAR-1CH,0001,1.0"

    def __init__(self, listen: str, coil: CoilSim, axis: int, max_current_a: float = 1.5) -> None:
        super().__init__(listen)
        self.coil = coil
        self.axis = axis
        self.max_current_a = max_current_a
        self.setpoint = 0.0
        self.output = False

    def _drive(self) -> None:
        with self.coil.lock:
            self.coil.current[self.axis] = self.setpoint if self.output else 0.0
            if not self.coil.output:
                self.coil._output(True)

    def command(self, head: str, arg: str) -> str | None:
        if head in ("OUTP", "OUTPUT"):
            self.output = arg.upper() in ("ON", "1")
            self._drive()
            return None
        if head in ("OUTP?", "OUTPUT?"):
            return "1" if self.output else "0"
        if head == "CURR":
            value = float(arg)
            if abs(value) > self.max_current_a:
                self.errors.append('-222,"Data out of range"')
                return None
            self.setpoint = value
            self._drive()
            return None
        if head == "CURR?":
            return f"{self.setpoint:.5f}"
        if head in ("MEAS:CURR?", "MEASURE:CURRENT?"):
            return f"{self.setpoint if self.output else 0.0:.5f}"
        raise KeyError(head)
