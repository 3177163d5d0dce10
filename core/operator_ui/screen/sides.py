"""The coverage in the operator's words: which sides of the unit still have to face the floor.

Why these words: the bins are directions of the field in the unit's own axes (x nose, y right, z down,
the autopilots' FRD body frame).  The Earth's field dips steeply into the ground at most production
sites (inclination 50–70°), so the field seen along the unit's +x means the nose points (mostly) down,
along −z that the unit is upside down, and so on.  Six sides, each the bins within ``SIDE_DEG`` of its
axis; a side whose bins are less than half covered is named — on the screen's sphere too, where the
same six words label the same six points.  Every side is named in one form, the part of the unit that
faces the floor ("still to face the floor: nose, top"): "turn down: nose up" or "level, top up" mixed
two forms a hurried operator had to translate.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from magline.core.fit.coverage import fibonacci_sphere

SIDES: tuple[tuple[str, tuple[float, float, float]], ...] = (
    ("nose", (1.0, 0.0, 0.0)), ("tail", (-1.0, 0.0, 0.0)),
    ("right side", (0.0, 1.0, 0.0)), ("left side", (0.0, -1.0, 0.0)),
    ("bottom", (0.0, 0.0, 1.0)), ("top", (0.0, 0.0, -1.0)),
)
MISSING_WORDS = "still to face the floor"  # what the names of the sides still missing follow
SIDE_DEG = 50.0  # a bin belongs to a side within this angle of its axis
COVERED = 0.5  # a side with less than this share of its bins covered is named


@lru_cache(maxsize=8)
def _members(n_bins: int) -> tuple[np.ndarray, ...]:
    centres = fibonacci_sphere(n_bins)
    cos = np.cos(np.radians(SIDE_DEG))
    return tuple(np.flatnonzero(centres @ np.array(axis) >= cos) for _, axis in SIDES)


def missing_sides(bins: list[int] | np.ndarray, n_bins: int) -> list[str]:
    """The sides still to face the floor, most missing first (empty once every side is covered enough)."""
    hit = np.zeros(n_bins, dtype=bool)
    hit[np.asarray(list(bins), dtype=int)] = True
    share = [(float(hit[m].mean()) if len(m) else 1.0, name) for (name, _), m in zip(SIDES, _members(n_bins),
                                                                                      strict=True)]
    return [name for covered, name in sorted(share) if covered < COVERED]
