"""Progress bars of the long runs of ``learn`` (limit tables, direct limits, the SMC): on standard
error only when it is a terminal, and never changing a number."""

from __future__ import annotations

import io
import sys

import numpy as np
import pytest
import tqdm

import planner.workers as workers
from planner.learn.posterior import smc
from planner.workers import process_map


class _Terminal(io.StringIO):
    """Standard error as a terminal would be (``isatty``), kept for reading."""

    def isatty(self):
        return True


class _EagerBar(tqdm.tqdm):
    """A bar redrawn at every update (no 0.1 s minimum interval: a test's runs are short), 100
    columns wide (a StringIO has no terminal size to follow)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **dict(kwargs, mininterval=0.0, dynamic_ncols=False, ncols=100))


def _on_terminal(monkeypatch) -> _Terminal:
    """Standard error a terminal, bars shown at once and at every update; returns it. Called in
    the test itself: pytest sets its own standard error again between a fixture and the test."""
    monkeypatch.setattr(workers, "PROGRESS_DELAY_S", 0.0)
    monkeypatch.setattr(tqdm, "tqdm", _EagerBar)
    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    return err


def _square(x):
    return x * x


def _log_likelihood(x):
    """A normal likelihood around 0.3 with sd 0.05 in every coordinate."""
    return -0.5 * np.sum(((x - 0.3) / 0.05) ** 2, axis=1)


@pytest.mark.parametrize("n_workers", [1, 2])
def test_process_map_is_quiet_off_a_terminal_and_keeps_the_order(capsys, n_workers):
    """Standard error captured (not a terminal): no bar, even with a label and no delay; the
    results in the jobs' order, forked or not."""
    jobs = list(range(7))
    assert process_map(_square, jobs, workers=n_workers, desc="limit table") == [j * j for j in jobs]
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("n_workers", [1, 2])
def test_process_map_counts_its_jobs_on_a_terminal(monkeypatch, n_workers):
    """On a terminal, once past the delay (0 here), the bar is labelled and reaches the job count;
    without a label there is none."""
    terminal = _on_terminal(monkeypatch)
    assert process_map(_square, list(range(5)), workers=n_workers, desc=None) == [0, 1, 4, 9, 16]
    assert terminal.getvalue() == ""
    assert process_map(_square, list(range(5)), workers=n_workers, desc="learn: table") == [0, 1, 4, 9, 16]
    assert "learn: table" in terminal.getvalue() and "5/5" in terminal.getvalue()


def test_smc_with_a_bar_draws_the_same_samples(monkeypatch):
    """The SMC's bar (beta and the tempering stage, shown on a terminal) changes no sample, weight
    or beta: the same seed gives the same run with and without it."""
    terminal = _on_terminal(monkeypatch)
    runs = [smc(_log_likelihood, [1.0, 1.0], rng=np.random.default_rng(4), n_particles=300, desc=desc)
            for desc in (None, "learn: posterior")]
    said = terminal.getvalue()
    assert "learn: posterior" in said and "beta 1.000" in said and "stage 1, move 6/6" in said, said[-300:]
    np.testing.assert_array_equal(runs[0].samples, runs[1].samples)
    assert runs[0].betas == runs[1].betas and runs[0].log_evidence == runs[1].log_evidence
    assert len(runs[0].betas) > 2  # tempered in several stages, so the bar had steps to show
