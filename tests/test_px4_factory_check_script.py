"""``scripts/px4_factory_store_check.py``, the parts that run without PX4: it reads PX4's BSON parameter file
as PX4's tinybson writes it, and it changes PX4's startup in one place only — the factory store loaded
before the user's file, as a board's startup does."""

from __future__ import annotations

import importlib.util
import struct

import pytest
from conftest import REPO

SCRIPT = REPO / "scripts" / "px4_factory_store_check.py"
SPEC = importlib.util.spec_from_file_location("px4_factory_store_check", SCRIPT)
check_script = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(check_script)


def bson(elements: list[tuple[int, str, bytes]]) -> bytes:
    """A BSON document (bsonspec.org): int32 size, then type, NUL-ended name, value; a 0 at the end."""
    body = b"".join(bytes([kind]) + name.encode() + b"\0" + value for kind, name, value in elements) + b"\0"
    return struct.pack("<i", len(body) + 4) + body


def test_the_store_s_parameters_are_read_as_bson_holds_them(tmp_path):
    store = tmp_path / "mtd_caldata"
    store.write_bytes(bson([(0x10, "CAL_MAG0_ID", struct.pack("<i", 197388)),
                            (0x01, "CAL_MAG0_XOFF", struct.pack("<d", 0.3932700157165527)),
                            (0x01, "CAL_MAG0_XSCALE", struct.pack("<d", -1.25))]))
    assert check_script.bson_doubles_and_ints(store) == {"CAL_MAG0_ID": 197388.0, "CAL_MAG0_XOFF": 0.3932700157165527,
                                                         "CAL_MAG0_XSCALE": -1.25}
    store.write_bytes(b"")  # the partition as the check creates it: empty, nothing in it
    assert check_script.bson_doubles_and_ints(store) == {}
    store.write_bytes(bson([(0x02, "NAME", struct.pack("<i", 2) + b"x\0")]))
    with pytest.raises(ValueError, match=r"BSON element type 0x2 at 'NAME'"):
        check_script.bson_doubles_and_ints(store)


def test_the_startup_loads_the_store_just_before_the_user_s_file_and_nothing_else_changes(tmp_path):
    build = tmp_path / "build"
    rcs = build / "etc" / "init.d-posix" / "rcS"
    rcs.parent.mkdir(parents=True)
    before = "set PARAM_FILE parameters.bson\nparam select $PARAM_FILE\nif [ -f $PARAM_FILE ]; then\n"
    rcs.write_text(before)
    (build / "etc" / "airframes").mkdir()
    etc = check_script.startup_with_factory_load(build, tmp_path / "work")
    changed = (etc / "init.d-posix" / "rcS").read_text()
    assert changed == before.replace("param select", check_script.LOAD_FACTORY + "param select")
    assert (etc / "airframes").is_dir() and rcs.read_text() == before  # the build itself untouched
    rcs.write_text("param import\n")
    with pytest.raises(SystemExit, match="has no 'param select"):
        check_script.startup_with_factory_load(build, tmp_path / "work")
