"""The sequencer: runs one unit through identify → … → record, never crashing the station."""

from magline.core.sequencer.context import Acquisition, RunContext
from magline.core.sequencer.sequencer import PHASES, Sequencer

__all__ = ["PHASES", "Acquisition", "RunContext", "Sequencer"]
