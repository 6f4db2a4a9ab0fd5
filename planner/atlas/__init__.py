"""Workspace atlas (``robomill atlas``): where in the cell, and at which rotation about the tool
axis, a tool removes the most material without chatter, computed on Dask.

Layers: :mod:`.grid` (the region), :mod:`.problem` (what every chunk shares), :mod:`.evaluate` (one
chunk: a pure function), :mod:`._kernel` (compiled ZOA envelope and best cut), :mod:`.engine`
(serial / local cluster / existing scheduler), :mod:`.run` (chunking, assembly, the best),
:mod:`.io` (Parquet), :mod:`.plots` (figures), :mod:`.cli`. :func:`demo_section` adds the two
figures of a small atlas to a demo report.
"""

from .grid import Region, default_rotations_deg
from .problem import AtlasProblem, build_problem
from .run import AtlasResult, run_atlas

__all__ = ["Region", "default_rotations_deg", "AtlasProblem", "build_problem", "AtlasResult", "run_atlas",
           "demo_section"]


def demo_section(report, robot, setup, out_dir, **kwargs):
    """Add the atlas figures of the example cell to a demo report (see :mod:`.demo`)."""
    from .demo import demo_section as _demo_section

    return _demo_section(report, robot, setup, out_dir, **kwargs)
