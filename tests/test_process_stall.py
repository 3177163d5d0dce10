"""The station process stops for a while mid-tumble: a stall of its own, not the vehicle's silence.

A paused VM, a long garbage collection or a starved CI worker stops every thread of the station for
seconds.  A wait for the stream under way then came back past its deadline without having listened,
and the link was declared lost ("nothing received for 3 s") — a CI run ERRORed a good ArduPilot unit
so; on PX4 the same wait would have said the compass delivers no readings.  See core/links/listening.py.
"""

from __future__ import annotations

import os
import subprocess

import pytest
from simstation import FAST_SENSOR_HZ, write_station

from magline.core.plugins import hookimpl, load_plugins
from magline.core.record import Outcome
from magline.core.sequencer import Sequencer
from magline.core.station import load_station
from magline.sim import create_sim

BACKENDS = {
    # flavour: (listen, station file, the product's options)
    "ardupilot": ("tcp:127.0.0.1:0", "ardupilot-sim.yaml",
                  {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0, "prearm_wait_s": 0.3}),
    "px4": ("udp:127.0.0.1:0", "px4-sim.yaml", {"connect_timeout_s": 5.0, "boot_timeout_s": 10.0}),
}


class StopTheProcess:
    """SIGSTOP this whole process from another one for ``seconds``, once, mid-tumble."""

    def __init__(self, seconds: float) -> None:
        self.seconds, self.helper = seconds, None

    @hookimpl
    def magline_acquisition_progress(self, run, attempt, samples, coverage, target):
        if samples >= 60 and self.helper is None:  # a moment later the station is back waiting for the stream
            pid = os.getpid()
            self.helper = subprocess.Popen(["sh", "-c", f"sleep 0.05; kill -STOP {pid}; sleep {self.seconds}; "
                                            f"kill -CONT {pid}"])


@pytest.mark.parametrize("flavour", sorted(BACKENDS))
def test_a_stall_of_the_station_process_is_not_a_lost_link(tmp_path, flavour):
    """Stopped for 3 s (longer than the 2 s stream wait and the 2.5 s silence a lost link is): the
    vehicle, simulated in this process and so stopped with it, is heard again and the unit passes."""
    listen, example, options = BACKENDS[flavour]
    stop = StopTheProcess(3.0)
    # speed 2 (≈650°/s): at 20 messages a second the accelerometer must follow the unit between two of
    # its readings to be paired with the compass between them (at speed 5 they were 80° apart)
    with create_sim(flavour, listen, mag_rate_hz=FAST_SENSOR_HZ, workdir=tmp_path / "fc", seed=11,
                    boot_time_s=0.3, speed=2.0) as sim:
        _, host, port = sim.address.split(":")
        address = sim.address if flavour == "ardupilot" else f"udpout://{host}:{port}"  # MAVSDK's own form
        # a slow stream: between messages the station waits with nothing in its socket, as on any compass
        station = write_station(example, tmp_path, address, options, {"acquisition": {"rate_hz": 20.0, "samples": 200}})
        seq = Sequencer(load_station(station), load_plugins(extra=[stop]), tmp_path, sleep=lambda s: None)
        try:
            record = seq.run_unit(f"SN-STOP-{flavour}")
            health = sim.health()
        finally:
            seq.close()
    assert stop.helper is not None and stop.helper.wait(10) == 0  # the stop and the continue were both sent
    assert record.verdict is Outcome.PASS, (record.cause, health)
    acquire = next(p for p in record.phases if p.name == "acquire")
    assert acquire.duration_s >= 3.0  # the stop fell inside the tumble
