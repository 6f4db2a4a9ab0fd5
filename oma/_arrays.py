"""Small array helpers shared by every package (no physics)."""

from __future__ import annotations

import numpy as np

__all__ = ["readonly"]


def readonly(a, dtype=float) -> np.ndarray:
    """A read-only copy of ``a`` (the arrays of robomill's frozen result types)."""
    a = np.array(a, dtype=dtype)
    a.setflags(write=False)
    return a
