"""Power control: how the verify phase cycles the unit's power, chosen per product in the station file.

Why a plugin point: a commanded reboot is not a power cycle — firmware flushes pending writes on a
commanded reboot, not when power is cut — and some targets refuse the command.  Real lines cut
power through the fixture (a programmable supply, a relay, a USB hub).  This module defines the
protocol and the default method, ``link-reboot`` (the backend's own reboot command over the unit's
link: MAVLink's ``MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN``, INAV's ``MSP_REBOOT``, a line protocol's
``REBOOT``; ``mavlink-reboot``, its former name, is still accepted); ``plugins/power/`` adds
``scpi-supply`` and ``command``.  A power control never talks MAVLink itself: it drives the DUT backend's
``reboot`` / ``release_link`` / ``await_boot``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from magline.core.dut import DutBackend, OldBootRunning, after_power_cut
from magline.core.faults import StationFault
from magline.core.plugins import hookimpl

if TYPE_CHECKING:
    from magline.core.station.schema import PowerConfig


class PowerError(StationFault):
    """The fixture itself failed (supply error, command failed): the unit *errors*, it does not fail."""


@runtime_checkable
class PowerControl(Protocol):
    method: str

    def power_up(self) -> None:
        """Before the DUT is connected: make sure the unit is powered."""

    def cycle(self, dut: DutBackend) -> dict[str, float | str]:
        """Cut and restore power (or reboot), wait for the new boot; return figures and ``method``."""

    def finish(self) -> None:
        """End of the unit, also after errors: leave the fixture in the station's final state."""

    def close(self) -> None: ...


USB_FEEDS_IT = ("it is powered by USB as well — feed it from the fixture's supply only, or cut the USB port's "
                "power instead (power method usb-hub)")


def await_boot_after_cut(dut: DutBackend, on_at: float, cut: str, fed_by: str = USB_FEEDS_IT) -> dict[str, float]:
    """The new boot after a power cut (``cut``: what was switched off, in the operator's words).  A
    board whose uptime kept counting never lost power: something else feeds it (``fed_by`` says what,
    and what to do) — the USB cable, on a board that takes its power from USB too.  That is the
    fixture's fault, not the unit's: an ERROR, where a refused *commanded* reboot stays a FAIL."""
    try:
        with after_power_cut():  # the first answer of an old boot is the answer: it ran through the cut
            return dut.await_boot(on_at)
    except OldBootRunning as exc:
        raise PowerError(f"the board kept running through the {cut} (its uptime kept counting: {exc.uptime_s:.0f} s): "
                         f"{fed_by}") from exc


class LinkReboot:
    """The backend's own reboot command over the unit's link (the default; no fixture needed).  Why not
    called after MAVLink: INAV's and a third party's boards reboot by their own protocols, and a record
    that said ``mavlink-reboot`` of them said what did not happen."""

    method = "link-reboot"

    def power_up(self) -> None:
        return None

    def cycle(self, dut: DutBackend) -> dict[str, float | str]:
        start = time.monotonic()
        dut.reboot()
        return {"method": self.method, **dut.await_boot(start)}

    def finish(self) -> None:
        return None

    def close(self) -> None:
        return None


def create_link_reboot(config: PowerConfig, station_dir: Path, options: object) -> LinkReboot:
    return LinkReboot()


@hookimpl
def magline_register_power_controls(register):
    register("link-reboot", create_link_reboot, options="magline.core.station.no_options:NoOptions")
    # the former name: station files that say it keep working
    register("mavlink-reboot", create_link_reboot, options="magline.core.station.no_options:NoOptions")
