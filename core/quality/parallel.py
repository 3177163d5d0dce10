"""Every charted characteristic's capability, several at once on worker processes when the window is
large.

Why: a characteristic that is not normal and that Box-Cox cannot help gets the percentile method,
whose four shape fits cost about 80 ms whatever the window — an optimiser's iterations in Python, so
threads only contend for the interpreter's lock.  ``spc`` over 10,000 units of a line whose thirteen
characteristics are all skewed spent a second there; a quality engineer's PC has cores for it.  The
workers are forked after scipy.stats is imported, so each starts in milliseconds, and each answer is
the one the same call gives in this process (the fits and the Box-Cox bootstrap are deterministic).
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

import numpy as np

from magline.core.quality.capability import Capability, capability

# Windows with fewer values stay in this process: their report is ready well within a second either way
# (the fits cost about the same at any size; it is the read and the charts that grow), a fork costs
# 10–30 ms, and a process whose other threads serve a screen is better not forked for nothing.
PARALLEL_VALUES = 2000
MAX_WORKERS = 4

Job = tuple[np.ndarray, float | None, float | None, float]


def _one(job: Job) -> Capability:
    return capability(*job)


def capabilities(jobs: list[Job]) -> list[Capability]:
    """``capability(values, low, high, sigma_within)`` of each job, in order."""
    workers = min(len(jobs), os.cpu_count() or 1, MAX_WORKERS)
    large = sum(np.asarray(job[0]).size >= PARALLEL_VALUES for job in jobs)
    if workers < 2 or large < 2 or "fork" not in multiprocessing.get_all_start_methods():
        return [_one(job) for job in jobs]
    from scipy import stats  # noqa: F401 — imported before the fork: the workers inherit it

    try:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
            return list(pool.map(_one, jobs))
    except (OSError, BrokenProcessPool):  # no process to be had: the same answers, one after another
        return [_one(job) for job in jobs]
