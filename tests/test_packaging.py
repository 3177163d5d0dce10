"""Installed layout: everything under ``magline``; nothing named bare ``core`` or ``plugins``."""

from __future__ import annotations

import subprocess
import sys
import zipfile

from conftest import source_copy


def test_wheel_contains_only_the_magline_namespace(tmp_path):
    source = source_copy(tmp_path / "magline-src")  # built in the checkout, its build/ kept moved modules
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(tmp_path), str(source)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    wheel = next(tmp_path.glob("magline-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops <= {"magline", next(n.split("/")[0] for n in names if ".dist-info/" in n)}
    for required in ("magline/core/hookspecs.py", "magline/plugin/__init__.py", "magline/plugins/mock/dut.py",
                     "magline/stations/demo.yaml",
                     "magline/sim/vehicle.py", "magline/sim/truth/imu.py", "magline/sim/commands.py",
                     "magline/core/fit/geometric.py", "magline/core/results/migrations/env.py",
                     "magline/core/results/migrations/versions/0002_run_uuid.py"):
        assert required in names
    assert not any(n.startswith(("core/", "plugins/", "sim/")) for n in names)
    assert not any(n.startswith("magline/plugins/mock/sim") for n in names)  # the simulators have their own root


def test_importable_names():
    import magline.core
    import magline.plugins.mock
    import magline.sim

    assert magline.core.__file__ and magline.plugins.mock.__file__ and magline.sim.__file__


def test_mavlink_checksums_come_from_the_compiled_crc_and_agree_with_pymavlinks_own():
    """The installed ``fastcrc`` is the checksum pymavlink packs and checks every message with (a Python loop
    per byte otherwise, most of a message's cost), and it computes the same checksum."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    assert mavlink.x25crc is mavlink._x25crc_fast
    frame = mavlink.MAVLink_raw_imu_message(123456, 1, -2, 3, -4, 5, -6, 7, -8, 9, 0, 20).pack(
        mavlink.MAVLink(None, srcSystem=1, srcComponent=1))
    body = frame[1:-2]
    crc = mavlink._x25crc_fast(body)
    slow = mavlink._x25crc_slow(body)
    crc.accumulate(bytes([mavlink.MAVLink_raw_imu_message.crc_extra]))
    slow.accumulate(bytes([mavlink.MAVLink_raw_imu_message.crc_extra]))
    assert crc.crc == slow.crc == int.from_bytes(frame[-2:], "little")
