"""The sequencer: runs one unit through identify → … → record, never crashing the station.

Its names are imported on first use (:mod:`magline.core.lazy`).
"""

from __future__ import annotations

from magline.core.lazy import lazy_names

__all__, __getattr__, __dir__ = lazy_names(__name__, {
    "magline.core.sequencer.context": ("Acquisition", "RunContext"),
    "magline.core.sequencer.sequencer": ("PHASES", "Sequencer"),
})
