"""``usb-hub``: the power cycle of a board powered by USB, by switching its hub port with ``uhubctl``.

Why a method of its own: a flight controller on a fixture's USB hub takes its power from the port;
the fixture's supply cannot cut it (the station says so, :func:`~magline.plugin.await_boot_after_cut`)
and a commanded reboot is not a power cut.  uhubctl (Debian's ``uhubctl`` package) switches one port of
a hub with per-port power switching; the hub's location and the port come from the station file
(``uhubctl`` with no arguments lists both).  What uhubctl prints is read back: a hub that reports the
port still powered after "off" (a hub without per-port switching, which uhubctl cannot really turn
off) is an ERROR, not a power cycle that never happened.
"""

from __future__ import annotations

import re
import subprocess
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from magline.plugin import PowerError, await_boot_after_cut

if TYPE_CHECKING:
    from magline.plugin import DutBackend, PowerConfig


class UsbHubOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    location: Annotated[str, Field(min_length=1)]
    """The hub, as uhubctl names it: "1-1", "2-1.4"."""
    port: Annotated[int, Field(ge=1)]
    """The hub's port the slot's cable is in."""
    uhubctl: str | Annotated[list[str], Field(min_length=1)] = "uhubctl"
    """The program that switches the port (a list: the start of its command line)."""
    off_time_s: Annotated[float, Field(ge=0)] = 2.0
    """How long the port stays off (uhubctl's own default for a cycle)."""
    timeout_s: Annotated[float, Field(gt=0)] = 20.0
    """One uhubctl run."""
    final_state: Literal["on", "as-is"] = "on"
    """``on``: the port is switched on again if a unit stopped while it was off."""


class UsbHubPower:
    method = "usb-hub"

    def __init__(self, options: UsbHubOptions, cwd: Path) -> None:
        self.opts = options
        self.cwd = cwd
        self.is_off = False
        program = options.uhubctl
        self.argv = [program] if isinstance(program, str) else list(program)

    @property
    def where(self) -> str:
        return f"hub {self.opts.location} port {self.opts.port}"

    def _switch(self, state: str) -> None:
        argv = [*self.argv, "-l", self.opts.location, "-p", str(self.opts.port), "-a", state]
        try:
            done = subprocess.run(argv, cwd=self.cwd, capture_output=True, text=True, timeout=self.opts.timeout_s,
                                  check=False)
        except FileNotFoundError:
            raise PowerError(f"{self.argv[0]!r} is not installed (Debian: apt install uhubctl), or the station's "
                             "power option uhubctl names no program") from None
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise PowerError(f"uhubctl could not switch {self.where} {state}: {exc}") from exc
        if done.returncode != 0:
            said = (done.stderr or done.stdout).strip().splitlines()[-1:] or [f"exit status {done.returncode}"]
            raise PowerError(f"uhubctl could not switch {self.where} {state}: {said[0]}")
        now = _port_after(done.stdout, self.opts.port)
        if now is None or (state == "off") != (now == "off"):
            raise PowerError(f"uhubctl asked {self.where} {state} but the hub reports it "
                             f"{'still powered' if state == 'off' else 'off'}: a hub without per-port power "
                             "switching cannot cut a board's power (uhubctl's list of compatible hubs)")

    def power_up(self) -> None:
        self._switch("on")

    def cycle(self, dut: DutBackend) -> dict[str, float | str]:
        dut.release_link()
        self._switch("off")
        self.is_off = True
        off_at = time.monotonic()
        time.sleep(self.opts.off_time_s)
        on_at = time.monotonic()
        self._switch("on")
        self.is_off = False
        figures = await_boot_after_cut(dut, on_at, f"power cut of {self.where}",
                                       "it has a supply of its own (a power module, a battery, the fixture's "
                                       "supply) — cut that one instead (power method scpi-supply or command)")
        return {"method": self.method, "off_time_s": on_at - off_at, **figures}

    def finish(self) -> None:
        if self.is_off and self.opts.final_state == "on":
            self._switch("on")
            self.is_off = False

    def close(self) -> None:
        return None


def _port_after(printed: str, port: int) -> str | None:
    """The port's state in uhubctl's last status block ("off" or "power"), None when not printed."""
    states = re.findall(rf"^\s*Port {port}: [0-9a-f]{{4}} (\w+)", printed, flags=re.MULTILINE)
    return states[-1] if states else None


def create_usb_hub_power(config: PowerConfig, station_dir: Path, options: UsbHubOptions) -> UsbHubPower:
    return UsbHubPower(options, station_dir)
