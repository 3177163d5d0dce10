"""A simulated three-axis fluxgate read through a DAQ over SCPI (``MEAS:VOLT:DC? (@101,102,103)``).

The field it sees comes from a callable, so the same instrument serves as the Earth-field
reference of a tumble station (a constant field, optionally drifting or disturbed) and as the
reference inside a Helmholtz coil (the coil's field plus the ambient field).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from magline.sim.scpi_server import ScpiServer


class FluxgateSim(ScpiServer):
    identity = "magline,SIM-DAQ-FLUXGATE,0001,1.0"

    def __init__(self, listen: str, field_ut: Callable[[], NDArray], scale_ut_per_v: float = 10.0,
                 noise_ut: float = 0.01, seed: int | None = None) -> None:
        super().__init__(listen)
        self.field_ut = field_ut
        self.scale_ut_per_v = scale_ut_per_v
        self.noise_ut = noise_ut
        self.rng = np.random.default_rng(seed)

    def command(self, head: str, arg: str) -> str | None:
        if head in ("MEAS:VOLT:DC?", "MEASURE:VOLTAGE:DC?"):
            channels = [c for c in arg.strip("()@ ").split(",") if c]
            if len(channels) != 3:
                self.errors.append('-221,"Settings conflict; three channels expected"')
                return "0,0,0"
            b = np.asarray(self.field_ut(), float) + self.rng.normal(scale=self.noise_ut, size=3)
            return ",".join(f"{v / self.scale_ut_per_v:+.6E}" for v in b)
        raise KeyError(head)
