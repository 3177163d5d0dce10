"""magline run --record-mavlink: a unit's MAVLink traffic, both ways, in a tlog pymavlink reads; and
the recorded vehicle replayed to the backend, so that what the line saw becomes a test."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pymavlink import mavutil
from simstation import FAST_SENSOR_HZ, attempt_rows, write_station
from sqlalchemy import create_engine, select

from magline.core.cli import main
from magline.core.plugins import load_plugins
from magline.core.results.tables import runs
from magline.core.station import load_station
from magline.sim import create_sim
from magline.testing import mavlink_replay, read_tlog

AP = {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "prearm_wait_s": 0.3}
REBOOT = 246  # MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN
SET_MESSAGE_INTERVAL = 511  # MAV_CMD_SET_MESSAGE_INTERVAL
RAW_IMU, SCALED_IMU2, SCALED_IMU3 = 27, 116, 129  # the streams of compass 1, 2, 3


def messages(tlog):
    log = mavutil.mavlink_connection(str(tlog))
    out = []
    while (m := log.recv_match()) is not None:
        out.append(m)
    return out


def test_an_ardupilot_unit_is_recorded_both_ways_and_replays_to_the_backend(tmp_path, capsys):
    tlog = tmp_path / "line" / "unit.tlog"
    with create_sim("ardupilot", "tcp:127.0.0.1:0", workdir=tmp_path / "fc", seed=11, boot_time_s=0.3,
                    speed=5.0, mag_rate_hz=FAST_SENSOR_HZ) as sim:
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP,
                                {"acquisition": {"samples": 300}})
        assert main(["run", str(station), "--serial", "REC-1", "--record-mavlink", str(tlog)]) == 0
    assert f"MAVLink traffic: {tlog}" in capsys.readouterr().err
    recorded = messages(tlog)
    vehicle = [m for m in recorded if m.get_srcSystem() == 1]
    station_side = [m for m in recorded if m.get_srcSystem() != 1]
    assert any(m.get_type() == "HEARTBEAT" and m.autopilot == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
               for m in vehicle)
    stored = attempt_rows(tmp_path / "results.sqlite", "REC-1")
    line_raw = stored[0]["raw"]  # the first attempt's readings are the first the stream carried
    assert sum(m.get_type() == "RAW_IMU" for m in vehicle) >= sum(len(a["raw"]) for a in stored) > 0
    assert any(m.get_type() == "PARAM_SET" and m.param_id == "COMPASS_OFS_X" for m in station_side)
    assert any(m.get_type() == "COMMAND_LONG" and m.command == REBOOT for m in station_side)
    assert all(b.t >= a.t for a, b in zip(read_tlog(tlog), read_tlog(tlog)[1:], strict=False))

    # the same unit's vehicle, replayed: the backend reads exactly the readings the line stored
    product = load_station(station).products["AP-QUAD-200"]
    plugins = load_plugins()
    options = plugins.options("dut backend", "ardupilot", product.options, "options")
    with mavlink_replay(tlog) as replay:
        dut = plugins.dut_backends["ardupilot"](product.model_copy(update={"connection": replay.connection}), options)
        try:
            info = dut.connect()
            assert info.autopilot.lower().startswith("ardupilot") and info.sensors == [sim.magnetometers[0].device_id]
            dut.prepare()
            got = []
            for chunk in dut.samples(200.0):
                got.append(chunk.mag_ut)
                if sum(map(len, got)) >= len(line_raw):
                    break
        finally:
            dut.close()
    assert np.allclose(np.vstack(got)[:len(line_raw)], line_raw.mag_ut, atol=1e-4)


def test_a_px4_unit_over_mavsdk_is_recorded_both_ways(tmp_path):
    tlog = tmp_path / "px4.tlog"
    with create_sim("px4", "udp:127.0.0.1:0", workdir=tmp_path / "fc", seed=11, boot_time_s=0.3,
                    speed=5.0, mag_rate_hz=FAST_SENSOR_HZ) as sim:
        _, host, port = sim.address.split(":")
        station = write_station("px4-sim.yaml", tmp_path, f"udpout://{host}:{port}",
                                {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0}, {"acquisition": {"samples": 300}})
        assert main(["run", str(station), "--serial", "REC-PX4", "--record-mavlink", str(tlog)]) == 0
    kinds = {(m.get_srcSystem() == 1, m.get_type()) for m in messages(tlog)}
    assert {(True, "HEARTBEAT"), (True, "PARAM_VALUE"), (False, "PARAM_SET"), (False, "COMMAND_LONG")} <= kinds


def test_a_three_compass_unit_reads_its_calibrated_compasses_side_by_side_after_the_power_cycle(tmp_path):
    """Each compass streams at 10 Hz: read one after the other, the proof after the power cycle took
    three times as long.  On the wire: the three streams are all asked for before any is stopped, and
    their readings arrive interleaved; each compass's calibrated field is in the record."""
    tlog = tmp_path / "unit.tlog"
    with create_sim("ardupilot", "tcp:127.0.0.1:0", workdir=tmp_path / "fc", seed=11, boot_time_s=0.3,
                    speed=5.0, mag_rate_hz=FAST_SENSOR_HZ, mag_count=3) as sim:
        station = write_station("ardupilot-sim.yaml", tmp_path, sim.address, AP, {"acquisition": {"samples": 300}})
        assert main(["run", str(station), "--serial", "REC-3", "--record-mavlink", str(tlog)]) == 0
    recorded = messages(tlog)
    reboot = next(i for i, m in enumerate(recorded) if m.get_type() == "COMMAND_LONG" and m.command == REBOOT)
    after = recorded[reboot:]
    intervals = [(i, int(m.param1), m.param2) for i, m in enumerate(after)
                 if m.get_type() == "COMMAND_LONG" and m.command == SET_MESSAGE_INTERVAL]
    streams = {RAW_IMU, SCALED_IMU2, SCALED_IMU3}
    asked = {msg_id: i for i, msg_id, interval in intervals if msg_id in streams and interval > 0}
    stopped = [i for i, msg_id, interval in intervals if msg_id in streams and interval <= 0]
    assert set(asked) == streams and stopped and max(asked.values()) < min(stopped)
    kinds = [m.get_type() for m in after[max(asked.values()):min(stopped)]
             if m.get_srcSystem() == 1 and m.get_type() in ("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3")]
    assert len(set(kinds[:10])) == 3  # interleaved, not one stream's readings after another's
    engine = create_engine(f"sqlite:///{tmp_path / 'results.sqlite'}")
    with engine.connect() as conn:
        persistence = json.loads(conn.execute(select(runs.c.persistence).where(runs.c.serial == "REC-3")).scalar_one())
    engine.dispose()
    for prefix in ("", "mag2_", "mag3_"):
        assert persistence["figures"][prefix + "calibrated_field_ut"] == pytest.approx(48.0, rel=0.03)
