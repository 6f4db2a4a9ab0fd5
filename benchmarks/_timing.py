"""Timing shared by the benchmarks: medians of repeated runs, wall and CPU."""

from __future__ import annotations

import statistics
import time


def median_time(fn, repeats: int):
    """Median wall time and median CPU time of this process (the CPU time is what the run costs
    without the other users of a shared machine), s, and the last result."""
    wall, cpu, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu), out
