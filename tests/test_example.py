"""The bundled example cell: regenerated bit for bit by its script, and it says what the paper says."""

from __future__ import annotations

import filecmp
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from oma.record_io import read_record

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "kr500_acetal"


def _load_script():
    spec = importlib.util.spec_from_file_location("make_example", EXAMPLE / "make_example.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_example_regenerates_bit_for_bit(tmp_path):
    _load_script().main(["--out", str(tmp_path)])
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert written, "the script wrote nothing"
    for rel in written:
        assert filecmp.cmp(tmp_path / rel, EXAMPLE / rel, shallow=False), f"{rel} differs from the bundled file"


@pytest.mark.parametrize("name, duration", [("cut_short", 1.1), ("cut_long", 20.0)])
def test_records_are_the_papers_cut(name, duration):
    rec = read_record(EXAMPLE / "records" / name)
    assert rec.duration_s == pytest.approx(duration, abs=1.5 / rec.sample_rate_hz)
    assert rec.sample_rate_hz == 1000.0
    assert rec.cut.spindle_rpm == 2700.0 and rec.tool.teeth == 2
    # the laser tracker's 15 um resolution: every displacement sample is a multiple of it
    steps = rec.displacement / 1.5e-5
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
