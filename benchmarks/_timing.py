"""Timing shared by the benchmarks: medians of repeated runs, wall and CPU."""

from __future__ import annotations

import os
import statistics
import time


def _cpu_with_children() -> float:
    """CPU time of this process and of its children that have finished (forked workers), s."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def median_time(fn, repeats: int, *, children: bool = False):
    """Median wall time and median CPU time of this process (the CPU time is what the run costs
    without the other users of a shared machine; with ``children``, also that of the worker
    processes it forked and waited for), s, and the last result."""
    clock = _cpu_with_children if children else time.process_time
    wall, cpu, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), clock()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(clock() - c0)
    return statistics.median(wall), statistics.median(cpu), out
