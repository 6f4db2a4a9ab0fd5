"""Diagnosis: show where robomill's simulation disagrees with measured cuts, name the physical cause,
extend the model with it and measure how much better the extended model predicts (robomill
issues 6 and 10).

Layers: :mod:`.spectral`, :mod:`.response`, :mod:`.forcemodel`, :mod:`.closedloop` (numerics);
:mod:`.compare` (the three parts of the comparison and their error definitions); :mod:`.causes`
(one fit per candidate cause; the force-side ones in :mod:`.forcefits`, the cutting coefficients
re-fitted first in :mod:`.coefficients`, the practical floors in :mod:`.floors`); :mod:`.diagnose`
(scoring, naming, the :class:`Diagnosis` result);
:mod:`.chatter` (chatter detection); :mod:`.cases` (simulated hidden-effect cases for tests and
benchmarks); :mod:`.hurco` (reader and chatter table for the measured CNC cuts); :mod:`.shortcuts`
(what the paper's own identification gets wrong); :mod:`.plots` (matplotlib, imported only when a
plot is drawn).
"""

from .chatter import ChatterResult, detect_chatter
from .compare import Comparison, RecordComparison, compare_records
from .diagnose import CAUSE_NAMES, CandidateResult, Diagnosis, diagnose

__all__ = [
    "diagnose",
    "Diagnosis",
    "CandidateResult",
    "CAUSE_NAMES",
    "compare_records",
    "Comparison",
    "RecordComparison",
    "detect_chatter",
    "ChatterResult",
]
