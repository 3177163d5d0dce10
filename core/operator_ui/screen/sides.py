"""The coverage in the operator's words: which sides of the unit still have to face the ground.

Why these words: the bins are directions of the field in the unit's own axes (x nose, y right, z down,
the autopilots' FRD body frame).  The Earth's field dips steeply into the ground at most production
sites (inclination 50–70°), so the field seen along the unit's +x means the nose points (mostly) down,
along −z that the unit is upside down, and so on.  Six sides, each the bins within ``SIDE_DEG`` of its
axis; a side whose bins are less than half covered is named — on the screen's sphere too, where the
same six words label the same six points.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from magline.core.fit.coverage import fibonacci_sphere

SIDES: tuple[tuple[str, tuple[float, float, float]], ...] = (
    ("nose down", (1.0, 0.0, 0.0)), ("nose up", (-1.0, 0.0, 0.0)),
    ("right side down", (0.0, 1.0, 0.0)), ("left side down", (0.0, -1.0, 0.0)),
    ("level, top up", (0.0, 0.0, 1.0)), ("upside down", (0.0, 0.0, -1.0)),
)
SIDE_DEG = 50.0  # a bin belongs to a side within this angle of its axis
COVERED = 0.5  # a side with less than this share of its bins covered is named


@lru_cache(maxsize=8)
def _members(n_bins: int) -> tuple[np.ndarray, ...]:
    centres = fibonacci_sphere(n_bins)
    cos = np.cos(np.radians(SIDE_DEG))
    return tuple(np.flatnonzero(centres @ np.array(axis) >= cos) for _, axis in SIDES)


def missing_sides(bins: list[int] | np.ndarray, n_bins: int) -> list[str]:
    """The sides still to turn down, most missing first (empty once every side is covered enough)."""
    hit = np.zeros(n_bins, dtype=bool)
    hit[np.asarray(list(bins), dtype=int)] = True
    share = [(float(hit[m].mean()) if len(m) else 1.0, name) for (name, _), m in zip(SIDES, _members(n_bins),
                                                                                      strict=True)]
    return [name for covered, name in sorted(share) if covered < COVERED]
