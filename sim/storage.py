"""A simulated unit's non-volatile parameter storage: a JSON file, written atomically (the in-process mock
DUT's and every simulated flight controller's).

Why a real file: the verify phase must prove that a calibration survives a power cycle; with a
file, "survives" means exactly "was committed to storage before the power went".
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from magline.core.dut import ParamValue


class NvStorage:
    def __init__(self, path: Path) -> None:
        self.path = path

    def load(self) -> dict[str, ParamValue]:
        try:
            return json.loads(self.path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {}

    def save(self, params: dict[str, ParamValue]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=".nv-")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(params, fh, indent=1, sort_keys=True)
        os.replace(tmp, self.path)
