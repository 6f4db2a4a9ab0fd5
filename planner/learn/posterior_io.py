"""A posterior written beside its MAP model: ``robomill-modal/1`` with ``x_posterior`` (cli.md).

The file is an ordinary ``robomill-modal/1`` model (the maximum a posteriori one), so every reader
of modal models reads it (they ignore ``x_`` keys). Beside it::

    x_posterior:
      format: robomill-posterior/1
      parameters: [frequency, stiffness, damping, Ktc, Krc]
      reference:                     # the prior the samples multiply
        natural_frequency_hz: [...]
        stiffness_N_m: [...]
        damping_ratio: [...]
        Ktc_N_m2: 7.0e8
        Krc_N_m2: 2.1e8
      prior_log_sd: [...]            # 0: a group held fixed
      likelihood: {mislabel: 0.05, boundary_scale: 0.03, ...}
      method: sdm                    # how the limits were computed (sdm, zoa, auto)
      mode_spread: [0, 0, 0]         # several modes: log-sd of each mode's own deviation from the
                                     # shared frequency, stiffness, damping factors (optional)
      map_coefficients: {Ktc_N_m2: ..., Krc_N_m2: ...}
      samples: [[u_f, u_k, u_zeta, u_Ktc, u_Krc], ...]   # log-multipliers, equally weighted,
                                                          # the MAP sample first
      cuts:                          # the test cuts learned from (optional; since session 28),
        - {spindle_rpm: ..., axial_depth_m: ..., radial_depth_m: ..., milling: down,
           outcome: stable, weight: 1.0,      # the label's weight (a detected outcome's confidence)
           probability_mislabelled: 0.02}     # the posterior's probability that the mark is wrong
                                              # (since session 29; absent for `uncertain` marks)

:func:`read_posterior` gives the samples back (``None`` for a model without them),
:func:`read_posterior_cuts` the cuts (``plan`` compares its cut with them:
:mod:`planner.learn.support`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from oma._fields import dump_yaml, load_yaml
from oma.cutting import CuttingCoefficients
from oma.errors import ModelError
from oma.io import atomic_write
from oma.modal_io import modal_model_to_dict, read_modal_model

from .likelihood import Likelihood
from .outcomes_io import OUTCOMES, CutTable
from .posterior import PARAMETERS, Posterior

__all__ = ["write_posterior_model", "read_posterior", "read_posterior_cuts", "PosteriorCuts", "POSTERIOR_FORMAT",
           "MAX_WRITTEN_SAMPLES"]

POSTERIOR_FORMAT = "robomill-posterior/1"
#: Samples written beside the MAP model at most (a random subset, the MAP first): 500 x 5 numbers
#: keep the file near 60 kB; ``lobes`` and ``plan`` use at most 400 of them.
MAX_WRITTEN_SAMPLES = 500


@dataclass(frozen=True)
class PosteriorCuts:
    """The test cuts a posterior was learned from, with the posterior's probability that each
    mark is wrong (``mislabelled``, NaN where the file does not say: an ``uncertain`` mark, or a
    file written before session 29)."""

    cuts: CutTable
    mislabelled: np.ndarray

    @property
    def n_cuts(self) -> int:
        return self.cuts.n_cuts


def posterior_to_dict(posterior: Posterior, *, max_samples: int = MAX_WRITTEN_SAMPLES,
                      cuts: CutTable | None = None, mislabelled=None) -> dict:
    """The ``robomill-modal/1`` mapping of the MAP model with ``x_posterior`` beside it (and the
    test ``cuts`` learned from, when given, with the posterior probability that each mark is wrong,
    ``mislabelled``, where it is finite)."""
    post = posterior.thinned(max_samples)
    model, coef = posterior.map_model()
    ref = posterior.reference
    doc = modal_model_to_dict(model)
    doc["x_posterior"] = {
        "format": POSTERIOR_FORMAT, "parameters": list(PARAMETERS),
        "reference": {"natural_frequency_hz": ref.natural_frequency_hz, "stiffness_N_m": ref.stiffness_N_m,
                      "damping_ratio": ref.damping_ratio, "Ktc_N_m2": posterior.coefficients.Ktc_N_m2,
                      "Krc_N_m2": posterior.coefficients.Krc_N_m2},
        "prior_log_sd": posterior.prior_log_sd, "likelihood": posterior.likelihood.to_dict(),
        "method": posterior.method, "mode_spread": posterior.mode_spread,
        "map_coefficients": {"Ktc_N_m2": coef.Ktc_N_m2, "Krc_N_m2": coef.Krc_N_m2},
        "samples": post.samples,
    }
    if cuts is not None:
        wrong = np.full(cuts.n_cuts, np.nan) if mislabelled is None else np.asarray(mislabelled, dtype=float)
        if wrong.shape != (cuts.n_cuts,):
            raise ValueError(f"mislabelled: one probability per cut ({cuts.n_cuts}), found shape {wrong.shape}")
        doc["x_posterior"]["cuts"] = [{**cuts.row(i), "weight": float(cuts.weight[i]),
                                       **({"probability_mislabelled": float(f"{wrong[i]:.3g}")} if np.isfinite(wrong[i]) else {})}
                                      for i in range(cuts.n_cuts)]
    return doc


def write_posterior_model(posterior: Posterior, path, *, max_samples: int = MAX_WRITTEN_SAMPLES,
                          cuts: CutTable | None = None, mislabelled=None) -> Path:
    """Write the MAP model with the posterior samples (and the test ``cuts``, with the probability
    that each mark is wrong: :func:`posterior_to_dict`) atomically."""
    target = Path(os.fspath(path))
    text = dump_yaml(posterior_to_dict(posterior, max_samples=max_samples, cuts=cuts, mislabelled=mislabelled))
    with atomic_write(target) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return target


def _array(node, key, path, shape_tail=None):
    try:
        a = np.asarray(node[key], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise ModelError(path, f"x_posterior.{key}", "a list of numbers", repr(node.get(key))[:60]) from None
    if not np.all(np.isfinite(a)) or (shape_tail is not None and (a.ndim != 2 or a.shape[1] != shape_tail)):
        raise ModelError(path, f"x_posterior.{key}", "finite numbers of the right shape", f"shape {a.shape}")
    return a


def read_posterior(path) -> Posterior | None:
    """The posterior of a model written by ``learn -o`` (``None`` when it has no ``x_posterior``).

    Raises
    ------
    ModelError
        The model is invalid, or ``x_posterior`` is malformed.
    """
    model = read_modal_model(path)
    node = load_yaml(path, error=ModelError).mapping.get("x_posterior")
    if node is None:
        return None
    if not isinstance(node, Mapping) or node.get("format") != POSTERIOR_FORMAT:
        raise ModelError(path, "x_posterior.format", POSTERIOR_FORMAT, repr(getattr(node, "get", lambda k: node)("format")))
    ref = node.get("reference")
    if not isinstance(ref, Mapping):
        raise ModelError(path, "x_posterior.reference", "a mapping", repr(ref)[:60])
    fn, k, z = (_array(ref, key, path) for key in ("natural_frequency_hz", "stiffness_N_m", "damping_ratio"))
    if not (fn.shape == k.shape == z.shape == (model.n_modes,)):
        raise ModelError(path, "x_posterior.reference", f"{model.n_modes} values per parameter", f"{fn.shape}")
    reference = replace(model, natural_frequency_hz=fn, stiffness_N_m=k, damping_ratio=z)
    coef = CuttingCoefficients(float(_array(ref, "Ktc_N_m2", path)), float(_array(ref, "Krc_N_m2", path)))
    samples = _array(node, "samples", path, shape_tail=len(PARAMETERS))
    sd = _array(node, "prior_log_sd", path)
    lk = node.get("likelihood") or {}
    if "noisy_mislabel" not in lk and 0 < float(lk.get("mislabel", 0.0)) < 0.5:
        lk = {**lk, "noisy_mislabel": lk["mislabel"]}  # written before session 12: the slab's median was the spike
    likelihood = Likelihood(**{k_: (bool(v) if k_ == "mislabel_average" else float(v)) for k_, v in lk.items()
                               if k_ in Likelihood.__dataclass_fields__})
    if samples.shape[0] == 0 or sd.shape != (len(PARAMETERS),):
        raise ModelError(path, "x_posterior.samples", "at least one sample of 5 log-multipliers", f"{samples.shape}")
    method = node.get("method", "sdm")
    if method not in ("sdm", "zoa", "auto"):
        raise ModelError(path, "x_posterior.method", "sdm, zoa or auto", repr(method))
    spread = np.zeros(3)
    if node.get("mode_spread") is not None:
        spread = _array(node, "mode_spread", path)
        if spread.shape != (3,) or np.any(spread < 0):
            raise ModelError(path, "x_posterior.mode_spread", "3 log-sds >= 0 (frequency, stiffness, damping)",
                             repr(node.get("mode_spread"))[:60])
    mark = np.full(samples.shape[0], -1.0)
    mark[0] = 0.0  # the writer puts the MAP sample first
    return Posterior(reference=reference, coefficients=coef, prior_log_sd=sd, samples=samples,
                     log_posterior=mark, likelihood=likelihood, method=method, mode_spread=spread)


def read_posterior_cuts(path) -> PosteriorCuts | None:
    """The test cuts a posterior was learned from (``x_posterior.cuts``), with the posterior's
    probability that each mark is wrong; ``None`` for a model without them (written before session
    28, or not by ``learn``).

    Raises
    ------
    ModelError
        ``x_posterior.cuts`` is malformed.
    """
    node = load_yaml(path, error=ModelError).mapping.get("x_posterior")
    rows = node.get("cuts") if isinstance(node, Mapping) else None
    if rows is None:
        return None
    if not isinstance(rows, list) or not rows:
        raise ModelError(path, "x_posterior.cuts", "a list of cuts", repr(rows)[:60])
    cols = {k: [] for k in ("spindle_rpm", "axial_depth_m", "radial_depth_m", "weight")}
    down, outcome, wrong = [], [], []
    for i, row in enumerate(rows):
        where = f"x_posterior.cuts[{i}]"
        if not isinstance(row, Mapping):
            raise ModelError(path, where, "a mapping", repr(row)[:60])
        for k, v in cols.items():
            try:
                x = float(row.get(k, 1.0 if k == "weight" else None))
            except (TypeError, ValueError):
                x = math.nan
            if not (math.isfinite(x) and x >= 0 and (x > 0 or k == "weight")):
                raise ModelError(path, f"{where}.{k}", "a positive number" if k != "weight" else "a weight >= 0",
                                 repr(row.get(k))[:60])
            v.append(x)
        if row.get("milling") not in ("up", "down"):
            raise ModelError(path, f"{where}.milling", "up or down", repr(row.get("milling"))[:60])
        if row.get("outcome") not in OUTCOMES:
            raise ModelError(path, f"{where}.outcome", " or ".join(OUTCOMES), repr(row.get("outcome"))[:60])
        down.append(row["milling"] == "down")
        outcome.append(OUTCOMES[row["outcome"]])
        p = row.get("probability_mislabelled", math.nan)
        if not (isinstance(p, (int, float)) and not isinstance(p, bool) and (math.isnan(p) or 0 <= p <= 1)):
            raise ModelError(path, f"{where}.probability_mislabelled", "a probability in [0, 1]", repr(p)[:60])
        wrong.append(float(p))
    n = len(rows)
    # the feed is not compared with the plan (the stability limit does not depend on it)
    cuts = CutTable(np.array(cols["spindle_rpm"]), np.array(cols["axial_depth_m"]), np.array(cols["radial_depth_m"]),
                    np.array(down), np.array(outcome), np.array(cols["weight"]), np.full(n, np.nan),
                    np.zeros(n, dtype=bool))
    return PosteriorCuts(cuts, np.array(wrong))
