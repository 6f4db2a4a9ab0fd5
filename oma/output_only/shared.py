"""Where the shared real data (``shared/data``, see its README) live: one helper for tests and
benchmarks."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["shared_dir"]


def shared_dir() -> Path:
    """``$ROBOMILL_SHARED`` when set, else ``<repository>/../shared`` (where CI puts it)."""
    env = os.environ.get("ROBOMILL_SHARED")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared"
