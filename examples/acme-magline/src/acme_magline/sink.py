"""A JSON-lines results sink: the plant's feed, one line per attempt and per finished run.

Meets ``magline.plugin.ResultSink``: run ids increase across restarts (read from the
file), attempts are written the moment they end, ``history`` rebuilds a unit's runs from the file.
"""

from __future__ import annotations

import json
from pathlib import Path

from magline.plugin import Numeric, Verdict
from pydantic import BaseModel, ConfigDict


class JsonLinesOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
    path: str = "magline-units.jsonl"
    """The JSON Lines file, relative to the station file."""
    raw: bool = False
    """Also write every raw reading of each attempt."""


class JsonLinesSink:
    def __init__(self, path: Path, raw: bool = False) -> None:
        self.path, self.raw = Path(path), raw
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.next_id = 1 + max((e["run_id"] for e in self._entries()), default=0)

    def _entries(self) -> list[dict]:
        if not self.path.exists():
            return []
        return [json.loads(line) for line in self.path.read_text(encoding="utf-8").splitlines() if line.strip()]

    def _write(self, entry: dict) -> None:
        with self.path.open("a", encoding="utf-8") as out:
            out.write(json.dumps(entry) + "\n")

    def begin(self, record) -> None:
        record.run_id, self.next_id = self.next_id, self.next_id + 1

    def save_attempt(self, record, attempt) -> None:
        if record.run_id is None:
            self.begin(record)
        entry = {"type": "attempt", "run_id": record.run_id, "attempt": attempt.attempt, "samples": attempt.samples,
                 "coverage": attempt.coverage, "accepted": bool(attempt.accepted), "refused": attempt.refused}
        if self.raw:
            entry["raw_ut"] = attempt.raw.mag_ut.tolist()
        self._write(entry)

    def finish(self, record) -> None:
        if record.run_id is None:
            self.begin(record)
        failed = [{"name": m.name, "value": m.value, "unit": m.unit, "low": m.low, "high": m.high}
                  for m in record.measurements if isinstance(m, Numeric) and m.verdict is Verdict.FAIL]
        self._write({"type": "run", "run_id": record.run_id, "serial": record.serial, "part": record.part,
                     "station_id": record.station_id, "line": record.line, "operator": record.operator,
                     "started": record.started, "finished": record.finished, "verdict": str(record.verdict),
                     "cause": record.cause, "limit_hash": record.limit_hash, "calibration": record.calibration,
                     "aborted_phase": record.aborted_phase, "failed": failed,
                     "accepted": {a.attempt: a.accepted for a in record.attempts}})

    def history(self, serial: str) -> list[dict]:
        entries = self._entries()
        out = []
        for run in (e for e in entries if e["type"] == "run" and e["serial"] == serial):
            accepted = {int(k): v for k, v in run.pop("accepted").items()}
            attempts = [{"attempt": a["attempt"], "samples": a["samples"], "coverage": a["coverage"],
                         "accepted": accepted.get(a["attempt"], a["accepted"]), "refused": a["refused"]}
                        for a in entries if a["type"] == "attempt" and a["run_id"] == run["run_id"]]
            out.append({"id": run.pop("run_id"), **{k: v for k, v in run.items() if k != "type"}, "attempts": attempts})
        return sorted(out, key=lambda r: r["id"])

    def location(self, record) -> str:
        return f"{self.path} run {record.run_id}"

    def close(self) -> None:
        return None
