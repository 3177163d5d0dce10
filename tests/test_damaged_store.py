"""A damaged SQLite store is refused before a unit is touched, and no command shows a traceback for
it (issue 31: 8 kB of garbage in the middle of the file)."""

from __future__ import annotations

import json

from magline.core.cli import main


def damage(path, at: float = 0.5, size: int = 8192) -> None:
    data = bytearray(path.read_bytes())
    start = int(len(data) * at) // 4096 * 4096
    data[start:start + size] = b"\xa5" * min(size, len(data) - start)
    path.write_bytes(bytes(data))


def test_a_damaged_store_is_refused_by_run_and_by_every_reading_command(make_station, capsys):
    station = make_station()
    store = station.parent / "magline-demo-results.sqlite"
    for serial in ("D-1", "D-2", "D-3"):
        assert main(["run", str(station), "--serial", serial]) == 0
    storage = station.parent / "magline-demo-storage.json"
    stored_before = storage.read_text(encoding="utf-8") if storage.exists() else None
    damage(store)
    before = store.read_bytes()
    capsys.readouterr()

    assert main(["run", str(station), "--serial", "D-4"]) == 2
    err = capsys.readouterr().err
    assert "is damaged" in err and "restore the file from a backup" in err and "Traceback" not in err
    assert store.read_bytes() == before  # nothing written into the damaged file
    assert (storage.read_text(encoding="utf-8") if storage.exists() else None) == stored_before  # DUT untouched

    for command in (["export"], ["spc"], ["history", "D-1"], ["show", "1"], ["export", "--raw"]):
        assert main([*command, "--station", str(station)]) == 2, command
        err = capsys.readouterr().err
        assert "is damaged" in err and "Traceback" not in err, (command, err)


def test_a_file_that_is_no_database_is_refused_the_same_way(make_station, capsys):
    station = make_station()
    (station.parent / "magline-demo-results.sqlite").write_text(json.dumps({"not": "a database"}) * 200)
    assert main(["run", str(station), "--serial", "X-1"]) == 2
    assert "is damaged (file is not a database)" in capsys.readouterr().err
