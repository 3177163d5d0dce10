"""FAIL against ERROR, fault by fault: the unit is failed only when it was judged bad.

The classification table of the README, tested per backend and transport against real sockets:
nothing listening, a port that never accepts, one that never answers, every simulator fault, and a
vehicle that closes its TCP link mid-acquisition.  Every timeout is a deadline.
"""

from __future__ import annotations

import contextlib
import time

import pytest
from dead_ports import never_accepting_port, refused_port, silent_port
from simstation import FAST_SENSOR_HZ, attempt_rows, run_unit, stored_attempts, write_station

from magline.core.plugins import hookimpl, load_plugins
from magline.core.record import Outcome
from magline.core.sequencer import Sequencer
from magline.core.station import load_station
from magline.sim import SimFaults, create_sim
from magline.sim.supply import SupplySim
from magline.testing.faults import ARDUPILOT_FAULTS, PX4_FAULTS, WARM_UP

# Every fault case below has its board there: it connects with the deadline a line gives a present board (a
# MAVSDK server starting on a loaded machine once outlasted 1 s); the boot deadline is short to keep the
# cases whose board never comes back quick.  Where no vehicle is, the connect deadline is 1 s (NO_VEHICLE).
AP = {"connect_timeout_s": 5.0, "boot_timeout_s": 3.0, "prearm_wait_s": 0.3}
PX4 = {"connect_timeout_s": 5.0, "boot_timeout_s": 3.0}
NO_VEHICLE = {"connect_timeout_s": 1.0}
DEADLINE_SLACK_S = 4.0  # a deadline of 1 s may overrun by a poll and a close, never by a TCP retry cycle


def dead_address(kind: str, backend: str, port: int) -> str:
    if backend == "ardupilot":
        return {"tcp": f"tcp:127.0.0.1:{port}", "udp": f"udpout:127.0.0.1:{port}"}[kind]
    return {"tcp": f"tcpout://127.0.0.1:{port}", "udp": f"udpout://127.0.0.1:{port}"}[kind]


CASES = [("ardupilot", "tcp", refused_port), ("ardupilot", "tcp", never_accepting_port),
         ("ardupilot", "tcp", silent_port), ("ardupilot", "udp", lambda: silent_port("udp")),
         ("px4", "tcp", refused_port), ("px4", "tcp", never_accepting_port), ("px4", "tcp", silent_port),
         ("px4", "udp", lambda: silent_port("udp"))]


@pytest.mark.parametrize(("backend", "transport", "port_kind"), CASES,
                         ids=[f"{b}-{t}-{k.__name__ if hasattr(k, '__name__') else 'silent'}" for b, t, k in CASES])
def test_no_vehicle_is_an_error_within_the_connect_deadline(tmp_path, backend, transport, port_kind):
    example = {"ardupilot": "ardupilot-sim.yaml", "px4": "px4-sim.yaml"}[backend]
    options = {**(AP if backend == "ardupilot" else PX4), **NO_VEHICLE}
    with port_kind() as port:
        station = write_station(example, tmp_path, dead_address(transport, backend, port), options)
        started = time.monotonic()
        record = run_unit(station)
        elapsed = time.monotonic() - started
    assert record.verdict is Outcome.ERROR, record.cause
    assert "within 1 s" in record.cause and "answered" in record.cause
    assert elapsed < options["connect_timeout_s"] + DEADLINE_SLACK_S
    assert "Error:" not in record.cause  # no Python class names for the operator


@pytest.mark.parametrize(("backend", "example"), [("ardupilot", "ardupilot-sim.yaml"), ("inav", "inav-sim.yaml")])
def test_an_address_where_nothing_listens_is_told_at_once_not_after_the_connect_timeout(tmp_path, backend, example):
    """A station started before its simulator (or on a wrong port) waited its whole connect timeout on a
    refused TCP connection: refused for NOTHING_LISTENS_S on the first connection, the unit is an ERROR
    that names the address, however long the timeout."""
    from magline.plugin import NOTHING_LISTENS_S

    with refused_port() as port:
        address = f"tcp:127.0.0.1:{port}"
        station = write_station(example, tmp_path, address, {"connect_timeout_s": 60.0, "boot_timeout_s": 60.0})
        started = time.monotonic()
        record = run_unit(station)
        elapsed = time.monotonic() - started
    assert record.verdict is Outcome.ERROR and f"nothing listens on {address}" in record.cause, record.cause
    assert NOTHING_LISTENS_S <= elapsed < 60.0  # told when the refusals have lasted, long before the timeout


@pytest.mark.parametrize("case", PX4_FAULTS, ids=[c.name for c in PX4_FAULTS])
def test_each_px4_firmware_fault_fails_the_post_power_cycle_proof(tmp_path, case):
    """Issue 50: the firmware stores and reads back every value as written but applies it otherwise
    (or the offset moved at the power cut): the unit FAILs at verify, never before and never an ERROR."""
    workdir = tmp_path / "fc"
    workdir.mkdir()
    with contextlib.ExitStack() as stack:
        sim = stack.enter_context(create_sim("px4", "udp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir,
                                             mag_count=case.mags, seed=11, boot_time_s=0.3, speed=5.0,
                                             faults=SimFaults.parse(list(case.faults))).start())
        product = {}
        if case.supply:
            supply = stack.enter_context(SupplySim("tcp:127.0.0.1:0", board=sim))
            product["power"] = {"method": "scpi-supply", "options": {"resource": supply.visa_resource,
                                                                     "off_time_s": 0.3, "settle_s": 0.1}}
        _, host, port = sim.address.split(":")
        options = {**PX4, **PASSING}
        station = write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}", options,
                                {"products": {"PX4-X500-100": product}, "acquisition": case.acquisition})
        record = run_unit(station, "SN-F")
    assert record.verdict is Outcome.FAIL, record.cause
    assert [p.name for p in record.phases if p.outcome is Outcome.FAIL] == ["verify"], record.cause
    assert case.words in record.cause, record.cause
    if case.supply:
        assert record.persistence["method"] == "scpi-supply"


def ap_sim(tmp_path, faults=None, **kw):
    workdir = tmp_path / "fc"
    workdir.mkdir(exist_ok=True)
    return create_sim("ardupilot", "tcp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=workdir, seed=11,
                      boot_time_s=0.3, speed=5.0, faults=faults, **kw).start()


# A case that must pass gets the backend's own boot deadline: the 3 s above is short to keep the failing
# cases quick, and with 2 % of packets lost a retried request on a loaded machine can pass it.
PASSING = {"boot_timeout_s": 10.0}


@pytest.mark.parametrize("case", ARDUPILOT_FAULTS, ids=[c.name for c in ARDUPILOT_FAULTS])
def test_each_simulator_fault_is_classified(tmp_path, case):
    outcome, words = Outcome(case.outcome), case.words
    with ap_sim(tmp_path, SimFaults.parse(list(case.faults)), mag_count=case.mags) as sim:
        # the backend's own 2 s stream timeout: a shorter one mistakes a loaded machine's stall for a fault
        options = {**AP, **(PASSING if case.passing_boot else {})}
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, options,
                                {"acquisition": case.acquisition})
        record = run_unit(station, "SN-F")
        board = sim.health()  # a CI run once lost this link for 3 s after a lost echo: whose silence was it
    assert record.verdict is outcome, f"{record.cause}\nthe board: {board}"
    assert words in record.cause
    assert case.missed(record) is None, case.missed(record)
    assert stored_attempts(tmp_path / "results.sqlite", "SN-F")  # raw data kept on every path
    if outcome is Outcome.ERROR and "unverified" in words:
        assert record.unverified_params and all(n.startswith("COMPASS_") for n in record.unverified_params)
        assert "COMPASS_OFS_X" in record.cause and "re-test the unit" in record.cause


def test_a_warm_up_caught_is_measured_again_and_the_settled_sensor_calibrated(tmp_path):
    """The board's compasses settle by 10 µT (τ 3 s) after power-on.  The drift test catches it (190 of
    190 benchmark runs); calibrated there and then, the unit carried the offset *during* the warm-up and
    the post-reboot field check FAILed the good unit in 2 of 190 runs (+3.1 %, +3.9 % against 3 %).  The
    station now measures again: the first attempt is kept, refused for the warm-up, with the reason and
    the operator's words, and the calibration written is a later attempt's.  The tumble right after the
    warm-up still falls inside it (its drift too small within the tumble for the drift test: 2 of 25
    benchmark runs FAILed the field check after the power cycle again): an attempt is taken only when
    its offset agrees with the previous one's: the second is refused too (the drift caught again, or the
    offset it moved since the first) unless it settled within the station's limit — how much warm-up is
    left by then depends on how fast the machine reached the tumbles, so either is right here, and the
    settle check's own test (tests/test_false_rejects.py) proves a moved offset is refused.

    The board is powered as its first tumble begins: the warm-up is then inside the tumble on any
    machine (counted from the simulator's start, a loaded machine reached the tumble once it was over,
    and the first attempt was rightly taken)."""
    from magline.sim.thermal import BoardWarmth

    class PoweredAtTheTumble:
        @hookimpl
        def magline_phase_started(self, run, phase):
            if phase == "acquire":
                with sim.lock:
                    now = time.monotonic()
                    sim.warmth = BoardWarmth(sim.warmth.tau_s, now)
                    sim.warmth.powered(True, now)

    with ap_sim(tmp_path, SimFaults.parse(list(WARM_UP.faults)), mag_count=WARM_UP.mags) as sim:
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, {**AP, **PASSING})
        seq = Sequencer(load_station(station), load_plugins(extra=[PoweredAtTheTumble()]), tmp_path,
                        sleep=lambda s: None)
        try:
            record = seq.run_unit("SN-W")
        finally:
            seq.close()
    assert record.verdict is Outcome.PASS, record.cause
    first = record.attempts[0]
    assert not first.accepted and first.refused.startswith("warm-up: the offset drifted"), first.refused
    assert len(record.attempts) >= 2 and record.attempts[-1].accepted
    second = record.attempts[1]  # still settling (the drift caught again, the offset moved), or settled and taken
    assert second.refused is None or second.refused.startswith("warm-up: "), second.refused
    lines = [line for phase in record.phases for line in phase.log]
    assert "operator: The magnetometer was still warming up — tumble again" in lines
    assert any(line.startswith("attempt 1: the offset drifted") and "measured again" in line for line in lines)
    assert WARM_UP.missed(record) is None
    stored = attempt_rows(tmp_path / "results.sqlite", "SN-W")
    assert [(a["accepted"], a["refused"]) for a in stored] == [(a.accepted, a.refused) for a in record.attempts]
    assert len(stored[0]["raw"]) == first.samples  # the refused attempt's raw data kept too


def test_a_vehicle_closing_its_tcp_link_is_a_lost_link_at_once(tmp_path, capfd):
    """The vehicle dies mid-acquisition: no 2 s stream timeout, no "EOF on TCP socket" flood."""
    sim = ap_sim(tmp_path)
    killed: list[float] = []

    class KillTheVehicle:
        @hookimpl
        def magline_acquisition_progress(self, run, attempt, samples, coverage, target):
            if samples >= 60 and not killed:
                sim.stop()
                killed.append(time.monotonic())

    station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, {**AP, "stream_timeout_s": 30.0})
    seq = Sequencer(load_station(station), load_plugins(extra=[KillTheVehicle()]), tmp_path, sleep=lambda s: None)
    try:
        record = seq.run_unit("SN-EOF")
    finally:
        seq.close()
        sim.stop()
    acquire = next(p for p in record.phases if p.name == "acquire")
    # the vehicle's end closes with a FIN, or — when bytes the station sent (a heartbeat) are still unread
    # in its socket as it closes — the kernel resets it instead: both are the vehicle gone, each said as it is
    assert record.verdict is Outcome.ERROR and "link" in record.cause, record.cause
    assert "the vehicle closed the TCP connection" in record.cause or \
        "the TCP connection was reset by the vehicle" in record.cause, record.cause
    assert acquire.duration_s < 30.0  # it did not wait for the stream timeout
    out = capfd.readouterr()
    assert "EOF on TCP socket" not in out.out + out.err


def test_a_px4_reboot_whose_ack_is_lost_is_proven_by_the_new_boot_not_failed_as_refused(tmp_path):
    """No answer to the reboot is not the autopilot saying no: a good unit used to FAIL "reboot refused by
    the autopilot: TIMEOUT" (the unit judged bad for a lost packet); the new boot proves the reboot."""
    (tmp_path / "fc").mkdir()
    with create_sim("px4", "udp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=tmp_path / "fc", seed=3,
                    boot_time_s=0.3, speed=5.0, faults=SimFaults.parse(["lose_reboot_ack"])) as sim:
        host, port = sim.address.split(":")[1:]
        record = run_unit(write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}", {**PX4, **PASSING}))
    assert record.verdict is Outcome.PASS, record.cause
    assert record.persistence["figures"]["uptime_at_reconnect_s"] < 5.0  # a new boot, not the old one


def test_an_ardupilot_reboot_whose_ack_is_lost_on_udp_is_proven_by_the_new_boot_not_failed(tmp_path):
    """Over UDP nothing closes when the board reboots: the station's three tries go unanswered and then
    hear the new boot.  That silence used to be a refusal (FAIL, "command 246 got no COMMAND_ACK"); the
    new boot proves the reboot, as on TCP where the closing link says it."""
    (tmp_path / "fc").mkdir()
    with create_sim("ardupilot", "udp:127.0.0.1:0", mag_rate_hz=FAST_SENSOR_HZ, workdir=tmp_path / "fc", seed=3,
                    boot_time_s=0.3, speed=5.0, faults=SimFaults.parse(["lose_reboot_ack"])) as sim:
        host, port = sim.address.split(":")[1:]
        record = run_unit(write_station("ardupilot-sim.yaml", tmp_path, f"udpout:{host}:{port}",
                                        {**AP, **PASSING}))
    assert record.verdict is Outcome.PASS, record.cause
    assert record.persistence["figures"]["uptime_at_reconnect_s"] < 5.0  # a new boot, not the old one
