"""Wall-clock timing of jitted calls, as the 2022 paper reports runtimes (Table 2): the mean and
standard deviation, over several runs, of the average time of one call."""

from __future__ import annotations

import time
from typing import Callable

import jax
import numpy as np


def time_call(fn: Callable[[], object], *, calls: int = 100, runs: int = 5, warmup: int = 3) -> tuple[float, float]:
    """``(mean, std)`` seconds per call of ``fn`` (waiting for its result each call, as a frame
    loop must): ``runs`` runs of ``calls`` calls each, after ``warmup`` calls (compilation)."""
    for _ in range(warmup):
        jax.block_until_ready(fn())
    per_call = []
    for _ in range(runs):
        t0 = time.perf_counter()
        for _ in range(calls):
            jax.block_until_ready(fn())
        per_call.append((time.perf_counter() - t0) / calls)
    return float(np.mean(per_call)), float(np.std(per_call))
