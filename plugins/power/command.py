"""``command``: cut and restore power by running external programs (a USB hub switch, a relay
tool, a simulator process).  Commands are argument lists run without a shell; a non-zero exit,
a timeout or a missing program errors the unit with the program's own message."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from magline.plugin import PowerError, await_boot_after_cut

if TYPE_CHECKING:
    from magline.plugin import DutBackend, PowerConfig


class CommandOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    off: Annotated[list[str], Field(min_length=1)]
    """The command line that switches the unit's power off."""
    on: Annotated[list[str], Field(min_length=1)]
    """The command line that switches it on."""
    off_time_s: Annotated[float, Field(ge=0)] = 1.0
    """How long the power stays off."""
    timeout_s: Annotated[float, Field(gt=0)] = 30.0
    """One command's run."""
    final_state: Literal["on", "as-is"] = "on"
    """``on``: the power is switched on again if a unit stopped while it was off."""


class CommandPower:
    method = "command"

    def __init__(self, options: CommandOptions, cwd: Path) -> None:
        self.opts = options
        self.cwd = cwd
        self.is_off = False

    def _run(self, which: str, argv: list[str]) -> None:
        try:
            done = subprocess.run(argv, cwd=self.cwd, capture_output=True, text=True, timeout=self.opts.timeout_s,
                                  check=False)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise PowerError(f"power-{which} command {argv[0]!r} failed: {exc}") from exc
        if done.returncode != 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or [""]
            raise PowerError(f"power-{which} command {argv[0]!r} exited with {done.returncode}: {tail[0]}")

    def power_up(self) -> None:
        return None

    def cycle(self, dut: DutBackend) -> dict[str, float | str]:
        dut.release_link()
        self._run("off", self.opts.off)
        self.is_off = True
        off_at = time.monotonic()
        time.sleep(self.opts.off_time_s)
        on_at = time.monotonic()
        self._run("on", self.opts.on)
        self.is_off = False
        return {"method": self.method, "off_time_s": on_at - off_at,
                **await_boot_after_cut(dut, on_at, f"power-off command ({self.opts.off[0]})")}

    def finish(self) -> None:
        if self.is_off and self.opts.final_state == "on":
            self._run("on", self.opts.on)
            self.is_off = False

    def close(self) -> None:
        return None


def create_command_power(config: PowerConfig, station_dir: Path, options: CommandOptions) -> CommandPower:
    return CommandPower(options, station_dir)
