"""The result of fitting a candidate cause: :class:`Extension` (shared by the force, structure and
stability fits of :mod:`~planner.diagnosis.causes` and :mod:`~planner.diagnosis.forcefits`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from oma.modal import ModalModel
from stability.simulate import Effects

__all__ = ["Extension"]


@dataclass(frozen=True)
class Extension:
    """A fitted candidate cause.

    Attributes
    ----------
    cause : str
    part : str
        ``force``, ``structure`` or ``stability``.
    parameters : dict
        Fitted parameters, physical units in the key names.
    success : bool
    message : str
    prediction : list
        The part's prediction on the validation halves (per view), as the part's ``evaluate``
        takes it.
    other_predictions : dict
        Predictions of other parts the extension changes (``{"force": [...]}`` for process
        damping, whose flank force also acts on the forced vibration at the tooth harmonics).
    model : ModalModel or None
        The extended structure model (structure candidates with a single model).
    effects : Effects or None
        The fitted effect as a simulator extension (force candidates).
    evidence : dict
        Named arrays for the plots.
    """

    cause: str
    part: str
    parameters: dict
    success: bool
    message: str
    prediction: list = field(repr=False, default_factory=list)
    model: ModalModel | None = field(repr=False, default=None)
    effects: Effects | None = field(repr=False, default=None)
    evidence: dict = field(repr=False, default_factory=dict)
    other_predictions: dict = field(repr=False, default_factory=dict)


def _failed(cause, part, message) -> Extension:
    return Extension(cause, part, {}, False, message)


def _sumsq(x) -> float:
    """Sum of squares without BLAS ``ddot`` (multithreaded above ~10^4 elements, which costs
    milliseconds per call on a loaded machine)."""
    return float(np.einsum("i,i->", x, x))
