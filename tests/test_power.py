"""Power control in the verify phase: MAVLink reboot vs a true power cut (SCPI supply), fixture
commands, current-draw checks, supply errors and the supply's final state."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest
from simstation import FAST_SENSOR_HZ, run_unit, write_station

from magline.core.cli import main
from magline.core.plugins import load_plugins
from magline.core.record import Outcome
from magline.sim import create_sim
from magline.sim.supply import SupplySim

HERE = Path(__file__).parent
PX4_OPTIONS = {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0}
AP_OPTIONS = {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "prearm_wait_s": 0.3}


def supply_power(supply: SupplySim, **extra) -> dict:
    return {"method": "scpi-supply", "options": {"resource": supply.visa_resource, "off_time_s": 0.3,
                                                 "settle_s": 0.1, **extra}}


def px4_station(tmp_path, sim, options=None, power=None):
    _, host, port = sim.address.split(":")
    product = {"power": power} if power else {}
    return write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}", {**PX4_OPTIONS, **(options or {})},
                         {"products": {"PX4-X500-100": product}})


def px4_sim(workdir, save_duration_s: float = 1.5):
    # the autosave is due 300 ms after the writes and then runs 1.5 s (a slow flash)
    return create_sim("px4", "udp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ,
                      workdir=workdir, seed=5, boot_time_s=0.3, speed=5.0,
                      save_duration_s=save_duration_s, autosave_interval_s=0.0)


def test_the_registry_has_the_three_methods():
    assert {"link-reboot", "mavlink-reboot", "scpi-supply", "command"} <= set(load_plugins().power_controls)


def test_reboot_keeps_a_running_save_a_power_cut_loses_it(tmp_path):
    """Without the forced save: a commanded reboot waits for the save that started during its 400 ms
    delay, so the calibration survives; cutting the power does not wait, and verify catches the loss."""
    with px4_sim(tmp_path / "reboot" / "fc") as sim:
        record = run_unit(px4_station(tmp_path / "reboot", sim, {"force_save": False}))
        assert record.verdict is Outcome.PASS, record.cause
        assert record.persistence["method"] == "link-reboot"
    with px4_sim(tmp_path / "cut" / "fc") as sim, SupplySim("tcp:127.0.0.1:0", board=sim) as supply:
        record = run_unit(px4_station(tmp_path / "cut", sim, {"force_save": False}, supply_power(supply)))
        assert record.verdict is Outcome.FAIL
        assert [p.name for p in record.phases if p.outcome is Outcome.FAIL] == ["verify"]
        assert "did not survive the power cycle" in record.cause
        assert record.persistence["method"] == "scpi-supply"
    with px4_sim(tmp_path / "shipped" / "fc", save_duration_s=0.3) as sim, \
            SupplySim("tcp:127.0.0.1:0", board=sim) as supply:
        record = run_unit(px4_station(tmp_path / "shipped", sim, power=supply_power(supply)))
        # the forced save, and the backend's wait for it to finish, make it survive the cut
        assert record.verdict is Outcome.PASS, record.cause
        figures = record.persistence["figures"]
        assert figures["off_time_s"] >= 0.3 and figures["current_after_power_on_a"] == pytest.approx(0.35, abs=0.11)
        assert figures["time_to_heartbeat_s"] > 0
        # safety order: limits before the output goes on, every time
        log = supply.log
        first_on = log.index("OUTP ON")
        assert any(c.startswith("CURR ") for c in log[:first_on]) and any(c.startswith("VOLT ") for c in log[:first_on])
        assert supply.output is True  # final state "on" (the default)


def test_a_commanded_reboot_goes_straight_on_after_the_forced_save(tmp_path):
    """Issue 27: the save's fixed wait is only for a supply cut.  A commanded reboot waits for the save
    by itself (PX4's shutdown lock): with a slow flash and a 20 s settle time the calibration survives
    and nothing waited the 20 s (a wait that long would show in the phases whatever the machine)."""
    with px4_sim(tmp_path / "fc") as sim:
        record = run_unit(px4_station(tmp_path, sim, {"save_settle_s": 20.0}))
        assert record.verdict is Outcome.PASS, record.cause
        assert record.persistence["method"] == "link-reboot"
    durations = {p.name: p.duration_s for p in record.phases}
    assert durations["persist"] + durations["verify"] < 20.0


@pytest.mark.parametrize("fault,expect", [("dead_board", "draws 0.000 A after power-on, outside [0.05, 1.2] A "
                                                         "(dead board or not connected)"),
                                          ("short", "draws 1.500 A after power-on, outside [0.05, 1.2] A "
                                                    "(short circuit or overload)")])
def test_a_board_drawing_no_or_too_much_current_fails_with_the_figure(tmp_path, fault, expect):
    with px4_sim(tmp_path / "fc") as sim, SupplySim("tcp:127.0.0.1:0", board=sim, fault=fault) as supply:
        sim.power_off()  # the fixture starts with the output off
        supply.output = False
        record = run_unit(px4_station(tmp_path, sim, power=supply_power(supply, final_state="off")))
        assert record.verdict is Outcome.FAIL
        assert expect in record.cause
        assert supply.output is False  # final state restored after the failure


def test_a_supply_error_errors_the_unit(tmp_path):
    with px4_sim(tmp_path / "fc") as sim, SupplySim("tcp:127.0.0.1:0", board=sim, fault="output_error") as supply:
        sim.power_off()
        record = run_unit(px4_station(tmp_path, sim, power=supply_power(supply)))
        assert record.verdict is Outcome.ERROR
        assert "reported during output on" in record.cause and "-300" in record.cause


def test_an_unreachable_supply_errors_the_unit(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with px4_sim(tmp_path / "fc") as sim:
        record = run_unit(px4_station(tmp_path, sim, power={
            "method": "scpi-supply", "options": {"resource": f"TCPIP0::127.0.0.1::{port}::SOCKET"}}))
        assert record.verdict is Outcome.ERROR
        assert f"TCPIP0::127.0.0.1::{port}::SOCKET" in record.cause and "Connection refused" in record.cause


def test_command_method_drives_a_simulator_process_off_and_on(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    fc = tmp_path / "fc"
    fc.mkdir()
    pidfile = str(tmp_path / "sim.pid")
    sim_args = ["ardupilot", "--listen", f"tcp:127.0.0.1:{port}", "--workdir", str(fc), "--boot-time", "0.2",
                "--speed", "5", "--seed", "3", "--mag-rate", str(FAST_SENSOR_HZ)]
    switch = [sys.executable, str(HERE / "power_switch.py")]
    on = [*switch, "on", pidfile, "--", *sim_args]
    assert subprocess.run(on, timeout=30).returncode == 0  # the fixture powers the unit up
    try:
        power = {"method": "command", "options": {"off": [*switch, "off", pidfile], "on": on, "off_time_s": 0.2}}
        path = write_station("ardupilot-sim.yaml", tmp_path, f"tcp:127.0.0.1:{port}", AP_OPTIONS,
                             {"products": {"AP-QUAD-200": {"power": power}}})
        record = run_unit(path)
        assert record.verdict is Outcome.PASS, record.cause
        assert record.persistence["method"] == "command"
        assert record.persistence["figures"]["off_time_s"] >= 0.2
        assert Path(pidfile).exists()  # running again after the cycle
    finally:
        if Path(pidfile).exists():
            subprocess.run([*switch, "off", pidfile], timeout=30)


def test_a_failing_power_command_errors_the_unit_and_final_state_is_restored(tmp_path):
    with create_sim("ardupilot", "tcp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ,
                      workdir=tmp_path / "fc", seed=5, boot_time_s=0.2,
                    speed=5.0) as sim:
        marker = tmp_path / "powered-on-again"
        power = {"method": "command", "options": {
            "off": [sys.executable, "-c", "import sys; sys.exit(0)"],
            "on": [sys.executable, "-c", f"import sys, pathlib; pathlib.Path({str(marker)!r}).touch(); sys.exit(3)"],
            "off_time_s": 0.0}}
        path = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS,
                             {"products": {"AP-QUAD-200": {"power": power}}})
        record = run_unit(path)
        assert record.verdict is Outcome.ERROR
        assert "power-on command" in record.cause and "exited with 3" in record.cause
        assert marker.exists()


def test_station_check_names_an_unknown_power_method_with_its_line(make_station, capsys):
    path = make_station({"products": {"MOCK-100": {"power": {"method": "relay-board"}}}})
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "products.MOCK-100.power.method: unknown power control 'relay-board'" in err
    assert f"{path}:" in err and "link-reboot" in err


def test_a_third_party_power_control_plugs_in(tmp_path):
    """magline_register_power_controls: a plugin author's relay board, driving the simulator's power."""
    from magline.core.plugins import hookimpl
    from magline.core.sequencer import Sequencer
    from magline.core.station import load_station

    with create_sim("ardupilot", "tcp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ,
                      workdir=tmp_path / "fc", seed=5, boot_time_s=0.2,
                    speed=5.0) as sim:
        class Relay:
            method = "acme-relay"

            def __init__(self, config, station_dir):
                self.channel = config.options["channel"]
                self.clicks: list[str] = []

            def power_up(self):
                self.clicks.append("on")

            def cycle(self, dut):
                import time
                dut.release_link()
                sim.power_off()
                self.clicks.append("off")
                sim.power_on()
                self.clicks.append("on")
                return {"method": self.method, "channel": float(self.channel), **dut.await_boot(time.monotonic())}

            def finish(self):
                pass

            def close(self):
                pass

        made: list[Relay] = []

        class AcmePlugin:
            @hookimpl
            def magline_register_power_controls(self, register):
                register("acme-relay", lambda config, station_dir, options: made.append(Relay(config, station_dir))
                         or made[-1])

        path = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP_OPTIONS,
                             {"products": {"AP-QUAD-200": {"power": {"method": "acme-relay",
                                                                     "options": {"channel": 4}}}}})
        seq = Sequencer(load_station(path), load_plugins(extra=[AcmePlugin()]), tmp_path, sleep=lambda s: None)
        record = seq.run_unit("SN-RELAY")
        seq.close()
        assert record.verdict is Outcome.PASS, record.cause
        assert made[0].clicks == ["on", "off", "on"] and sim.errors == []
        assert record.persistence["method"] == "acme-relay" and record.persistence["figures"]["channel"] == 4.0


class _SlowReconnects:
    """A clock and a vehicle for :func:`await_new_boot`: each reconnect takes ``takes_s`` of the budget it
    is given and fails when that budget is shorter (a MAVSDK server starting on a loaded machine), or
    always once the board is ``down``; the board answers with ``uptime`` (its old boot: it never reset)."""

    def __init__(self, takes_s: float, uptime: float, down_after: int | None = None) -> None:
        self.now, self.takes_s, self.uptime, self.down_after = 0.0, takes_s, uptime, down_after
        self.budgets: list[float] = []

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds

    def reconnect(self, budget_s: float) -> None:
        from magline.core.dut import DutError

        self.budgets.append(budget_s)
        if self.down_after is not None and len(self.budgets) > self.down_after:
            self.now += budget_s
            raise DutError("no PX4 vehicle answered")
        if budget_s < self.takes_s:
            self.now += budget_s
            raise DutError("no PX4 vehicle answered")
        self.now += self.takes_s


def test_a_board_that_ran_through_the_cut_is_told_so_even_when_a_reconnect_is_slow(monkeypatch):
    """Once the old boot answered, the last attempt near the deadline gets a fair time, not a tenth of a
    second: a USB-powered board that ran through a supply cut was once reported as one that "did not come
    back" (a CI run on a loaded machine), which hid why.  A board that really rebooted and stays down
    still fails a fair attempt: no answer is not an old boot."""
    from magline.core import dut
    from magline.core.dut import FAIR_ATTEMPT_S, LinkError, OldBootRunning, await_new_boot

    board = _SlowReconnects(takes_s=1.2, uptime=100.0)
    monkeypatch.setattr(dut, "time", board)
    with pytest.raises(OldBootRunning) as ran_through:
        await_new_boot(board.reconnect, lambda: board.uptime, 0.0, 3.0)
    assert ran_through.value.uptime_s == 100.0
    assert min(board.budgets) >= board.takes_s and board.budgets[-1] == FAIR_ATTEMPT_S  # every attempt fair

    rebooted = _SlowReconnects(takes_s=1.2, uptime=100.0, down_after=1)  # the old boot answered, then went down
    monkeypatch.setattr(dut, "time", rebooted)
    with pytest.raises(LinkError, match=r"did not come back within 3 s of the power cycle"):
        await_new_boot(rebooted.reconnect, lambda: rebooted.uptime, 0.0, 3.0)


def test_after_a_power_cut_the_first_answer_of_the_old_boot_is_the_answer(monkeypatch):
    """A commanded reboot's old boot may answer for a moment before it goes down, so that wait runs to its
    timeout; after the power was cut and restored nothing is about to go down: the first answer with the old
    uptime says the board ran through the cut, at once — not after a 30 s boot timeout (the test that met it
    shortened its timeout to 3 s, and a loaded machine's first reconnect outlasted that)."""
    from magline.core import dut
    from magline.core.dut import OldBootRunning, after_power_cut, await_new_boot

    board = _SlowReconnects(takes_s=1.2, uptime=100.0)
    monkeypatch.setattr(dut, "time", board)
    with after_power_cut(), pytest.raises(OldBootRunning, match="after the power cut: up 100 s") as ran_through:
        await_new_boot(board.reconnect, lambda: board.uptime, 0.0, 30.0)
    assert ran_through.value.uptime_s == 100.0 and len(board.budgets) == 1 and board.now < 2.0

    commanded = _SlowReconnects(takes_s=1.2, uptime=100.0)  # the same board after a reboot command
    monkeypatch.setattr(dut, "time", commanded)
    with pytest.raises(OldBootRunning, match="30 s after the reboot command"):
        await_new_boot(commanded.reconnect, lambda: commanded.uptime, 0.0, 30.0)
    assert commanded.now > 30.0 and len(commanded.budgets) > 1
