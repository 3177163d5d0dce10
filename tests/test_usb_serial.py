"""Units on USB (issue 48): both backends run a whole unit over a serial port — a simulator serving a
pseudo-terminal behind udev-style by-path and by-id links — the power cycle included, across the
re-enumeration at the reboot (the node goes away and comes back with another kernel number); and
what goes wrong on a serial line is an ERROR that says what: a wrong baud, a name that is not there,
a port another program holds, permission, the cable pulled, another board in the port."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from simstation import FAST_SENSOR_HZ, run_unit, stored_attempts, write_station

from magline.core.record import Outcome
from magline.sim import SimFaults, create_sim

PX4_OPTIONS = {"connect_timeout_s": 4.0, "boot_timeout_s": 8.0}
AP_OPTIONS = {"connect_timeout_s": 4.0, "boot_timeout_s": 8.0, "prearm_wait_s": 0.3}
PORT = "pci-0000:00:14.0-usb-0:3:1.0"  # the fixture's hub port 3, as udev names it


def usb_names(tmp_path: Path, board_serial: str = "3E0036000F51333130373938") -> tuple[Path, Path]:
    """A by-path and a by-id name for one board, laid out as udev lays /dev/serial out."""
    root = tmp_path / "dev" / "serial"
    return root / "by-path" / f"{PORT}-port0", root / "by-id" / f"usb-ArduPilot_fmuv3_{board_serial}-if00"


def sim(flavour: str, tmp_path: Path, listen: str, aliases: tuple[Path, ...] = (), **options):
    return create_sim(flavour, listen, workdir=tmp_path / "fc", seed=5, boot_time_s=0.3, speed=5.0,
                      mag_rate_hz=FAST_SENSOR_HZ, usb_aliases=tuple(str(a) for a in aliases), **options)


def station(flavour: str, tmp_path: Path, connection: str, **changes):
    example, options = ("px4-sim.yaml", PX4_OPTIONS) if flavour == "px4" else ("ardupilot-sim.yaml", AP_OPTIONS)
    return write_station(example, tmp_path, connection, {**options, **changes.pop("options", {})}, changes)


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_a_whole_unit_runs_over_usb_named_by_its_port_across_the_reboot(tmp_path, flavour):
    """The station names the fixture's port; the board re-enumerates at the power cycle (its node
    goes, another comes under the same names) and the new boot is proven through the new node."""
    by_path, by_id = usb_names(tmp_path)
    with sim(flavour, tmp_path, f"serial:{by_path}", (by_id,)) as board:
        record = run_unit(station(flavour, tmp_path, f"serial:{by_path}:115200"))
        nodes = list(board.link.devices)
    assert record.verdict is Outcome.PASS, record.cause
    assert record.persistence["method"] == "mavlink-reboot" and not record.persistence["mismatches"]
    written, read = record.params_written, record.params_read_back
    assert written and set(read) == set(written)  # every value back as float32 holds it
    assert all(read[n] == pytest.approx(v, rel=1e-6, abs=1e-7) for n, v in written.items())
    assert len(nodes) >= 2 and len(set(nodes)) == len(nodes), nodes  # another kernel number at each boot
    assert not by_path.exists() or os.path.realpath(by_path) == nodes[-1]


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_a_uart_at_the_wrong_baud_is_an_error_that_says_so_within_the_connect_timeout(tmp_path, flavour):
    """A telemetry UART at 57600 opened at 115200: framing garbage, nothing understood — an ERROR in
    connect naming the serial cause, and nothing written."""
    by_path, _ = usb_names(tmp_path)
    with sim(flavour, tmp_path, f"serial:{by_path}:57600") as board:
        record = run_unit(station(flavour, tmp_path, f"serial:{by_path}:115200"))
        garbled = board.link.garbled_bytes
    assert record.verdict is Outcome.ERROR and record.phases[1].name == "connect"
    assert record.phases[1].outcome is Outcome.ERROR
    assert "within 4 s" in record.cause and "wrong baud or a device that is not a flight controller" in record.cause
    assert garbled > 0 and not record.params_written


def test_a_name_that_is_not_there_is_an_error_listing_what_is_plugged_in(tmp_path):
    by_path, by_id = usb_names(tmp_path)
    with sim("ardupilot", tmp_path, f"serial:{by_path}", (by_id,)):
        missing = by_path.with_name("pci-0000:00:14.0-usb-0:4:1.0-port0")  # hub port 4: empty
        record = run_unit(station("ardupilot", tmp_path, f"serial:{missing}:115200"))
    assert record.verdict is Outcome.ERROR and record.phases[1].outcome is Outcome.ERROR
    assert f"{missing} is not there" in record.cause and f"plugged in: {by_path}" in record.cause


def test_a_port_another_program_holds_is_an_error_naming_it_not_a_hang(tmp_path):
    """ModemManager or a ground station with the port open: the station says who, before opening."""
    by_path, _ = usb_names(tmp_path)
    with sim("px4", tmp_path, f"serial:{by_path}") as board:
        holder = subprocess.Popen([sys.executable, "-c", "import sys, time; f = open(sys.argv[1], 'rb', buffering=0); "
                                   "print('open', flush=True); time.sleep(60)", str(by_path)],
                                  stdout=subprocess.PIPE, text=True)
        try:
            assert holder.stdout.readline().strip() == "open"
            record = run_unit(station("px4", tmp_path, f"serial:{by_path}:115200"))
        finally:
            holder.kill()
            holder.wait()
        assert board.link.devices  # the board was there all along
    assert record.verdict is Outcome.ERROR and record.phases[1].outcome is Outcome.ERROR
    assert f"{by_path} is held by python" in record.cause and f"(pid {holder.pid})" in record.cause


def test_a_port_the_station_may_not_open_names_the_group_to_join(tmp_path, monkeypatch):
    by_path, _ = usb_names(tmp_path)
    real_access = os.access
    with sim("ardupilot", tmp_path, f"serial:{by_path}") as board:
        node = board.link.device
        monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if p == node else real_access(p, mode, **kw))
        record = run_unit(station("ardupilot", tmp_path, f"serial:{by_path}:115200"))
    assert record.verdict is Outcome.ERROR
    assert f"permission denied on {node} (named {by_path})" in record.cause and "usermod -aG" in record.cause


def test_the_cable_pulled_mid_tumble_is_an_error_with_the_raw_data_kept(tmp_path):
    """The node vanishes during the acquisition (fault ``link_loss_after_s`` on a serial port): an
    ERROR in acquire, the readings that arrived stored, nothing written."""
    by_path, _ = usb_names(tmp_path)
    with sim("ardupilot", tmp_path, f"serial:{by_path}", faults=SimFaults(link_loss_after_s=1.0)) as board:
        path = station("ardupilot", tmp_path, f"serial:{by_path}:115200")
        record = run_unit(path)
        gone = not by_path.exists() and board.link.device is None
    assert gone
    assert record.verdict is Outcome.ERROR, record.cause
    assert [p.name for p in record.phases if p.outcome is Outcome.ERROR] == ["acquire"]
    assert "raw data kept" in record.cause and not record.params_written
    (samples, raw), = stored_attempts(path.parent / "results.sqlite", "SN-1")
    assert samples > 0 and len(raw) == samples


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_another_board_in_the_port_after_the_reboot_is_an_error_naming_both(tmp_path, flavour):
    """The by-path name comes back pointing at a board with another USB serial (the unit swapped in
    the fixture during its power cycle): the new boot proves nothing about the unit."""
    by_path, by_id = usb_names(tmp_path)
    other = by_id.with_name("usb-ArduPilot_fmuv3_99990000000000000000AAAA-if00")
    with sim(flavour, tmp_path, f"serial:{by_path}", (by_id,)) as board:
        original = board.link._plug

        def swapped() -> None:  # from the second boot on, the port's node has the other board's name
            original()
            if len(board.link.devices) > 1 and by_id.exists():
                by_id.rename(other)

        board.link._plug = swapped
        record = run_unit(station(flavour, tmp_path, f"serial:{by_path}:115200"))
    assert record.verdict is Outcome.ERROR, record.cause
    assert [p.name for p in record.phases if p.outcome is Outcome.ERROR] == ["verify"]
    assert f"came back as {other}, not {by_id}" in record.cause
