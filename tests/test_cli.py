"""The command line, in process (``main([...])``): exit codes, one-line errors, JSON on stdout."""

from __future__ import annotations

import json

import pytest

from planner.cli import main


def _run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_help_exits_zero(capsys):
    code, out, _ = _run(capsys, "--help")
    assert code == 0
    assert "simulate" in out


@pytest.mark.parametrize(
    "argv",
    [
        [],  # no subcommand
        ["frobnicate"],  # unknown subcommand
        ["simulate", "setup.yaml"],  # missing required options
        ["simulate", "setup.yaml", "--model", "m.yaml", "--rpm", "fast", "--depth", "1e-3", "--duration", "1", "-o", "r"],
    ],
)
def test_usage_errors_are_one_line_and_exit_2(capsys, argv):
    code, out, err = _run(capsys, *argv)
    assert code == 2
    assert out == ""
    assert len(err.strip().splitlines()) == 1
    assert "Traceback" not in err


def test_missing_file_is_exit_2_naming_the_file(capsys, tmp_path):
    missing = tmp_path / "nope.yaml"
    code, out, err = _run(
        capsys, "simulate", str(missing), "--model", str(missing), "--rpm", "2700", "--depth", "0.001",
        "--duration", "0.5", "-o", str(tmp_path / "rec"), "--json",
    )
    assert code == 2
    assert out == ""
    assert str(missing) in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "rec").exists()
