"""What every ``robomill`` subcommand shares (cli.md): exit codes, the one-line usage error, the
JSON-or-text output, atomic figure saving, and reading a structure (modal model or FRFs).

Command groups that live in their own sub-package (``planner.robot``, ...) register their parsers
through an ``add_parsers(sub)`` function and use these helpers; :mod:`planner.cli` wires them.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from oma.errors import InputError
from planner.report import jsonable

__all__ = ["EXIT_OK", "EXIT_NEGATIVE", "EXIT_INPUT", "EXIT_INTERNAL", "UsageError", "Parser", "emit",
           "add_json", "save_figure", "load_structure", "rpm_range", "coefficients", "add_model_options",
           "structure_from_args"]

EXIT_OK, EXIT_NEGATIVE, EXIT_INPUT, EXIT_INTERNAL = 0, 1, 2, 3


class UsageError(InputError):
    """A command-line argument that does not make sense (exit code 2)."""

    def __init__(self, option: str, expected: str, found: str):
        super().__init__(None, option, expected, found)

    def __str__(self) -> str:
        return f"{self.field}: expected {self.expected}, found {self.found}"


class Parser(argparse.ArgumentParser):
    """argparse that reports usage errors in one line and exit code 2, without printing usage."""

    def error(self, message):  # noqa: D401 - argparse API
        self.exit(EXIT_INPUT, f"robomill: {message} (see 'robomill --help')\n")


def emit(args, payload: dict, human: Callable[[dict], str] | str) -> None:
    """Print the JSON object (``--json``) or the human summary (stdout)."""
    if args.json:
        sys.stdout.write(json.dumps(jsonable(payload), indent=None) + "\n")
    else:
        text = human(payload) if callable(human) else human
        sys.stdout.write(text.rstrip("\n") + "\n")


def load_structure(paths: Sequence[str], axes: Sequence[str] | None = None, *, option: str = "--model",
                    axis_option: str = "--axis"):
    """A modal model (one ``.yaml``) or measured FRFs (``.csv``, ``.uff``, ``.frf``; several files
    are merged into one table, e.g. an XX and a YY ``.frf``, whose axes ``axis_option`` gives in
    order). ``option`` names the argument in error messages."""
    from oma.frf_io import read_frf
    from oma.frf_table import FRFTable
    from oma.modal_io import read_modal_model

    suffixes = [Path(p).suffix.lower() for p in paths]
    if any(s in (".yaml", ".yml") for s in suffixes):
        if len(paths) != 1:
            raise UsageError(option, "one modal model (.yaml), or FRF files only", f"{len(paths)} files")
        return read_modal_model(paths[0])
    for path, suffix in zip(paths, suffixes):
        if suffix not in (".csv", ".uff", ".unv", ".frf"):
            raise UsageError(option, "a modal model (.yaml) or FRF files (.csv, .uff, .frf)", repr(path))
    frf_files = [p for p, s in zip(paths, suffixes) if s == ".frf"]
    axes = list(axes or [])
    if len(axes) != len(frf_files):
        raise UsageError(axis_option, f"one axis (X, Y or Z) per .frf file ({len(frf_files)})", f"{len(axes)} axes")
    axis_of = dict(zip(frf_files, axes))
    tables = [read_frf(p, axis=axis_of.get(p)) for p in paths]
    return tables[0] if len(tables) == 1 else FRFTable.merge(tables)


def add_model_options(p: argparse.ArgumentParser, *, frf: bool) -> None:
    """``--model`` (a modal model; with ``frf`` also measured FRF files and ``--axis``) or, instead,
    ``--robot ROBOT --joints-deg Q1..Q6 [--tool-model MODEL]`` (cli.md)."""
    from planner.robot.cli import add_robot_options

    if frf:
        p.add_argument("--model", nargs="+", default=None,
                       help="modal model (.yaml), or measured FRF files (.csv, .uff, .frf)")
        p.add_argument("--axis", nargs="+", default=None, choices=["X", "Y", "Z"],
                       help="direction of each .frf file given to --model, in order")
    else:
        p.add_argument("--model", default=None, help="modal model (.yaml)")
    add_robot_options(p)


def structure_from_args(args, *, frf: bool = False):
    """The structure of ``--model`` (see :func:`load_structure`; a modal model only unless ``frf``)
    or of ``--robot ... --joints-deg ...`` (the calibrated robot's model at that pose)."""
    if getattr(args, "robot", None) is not None:
        if args.model is not None:
            raise UsageError("--robot", "either --model or --robot, not both", "both")
        from planner.robot.cli import model_from_robot_args

        return model_from_robot_args(args)
    for option in ("joints_deg", "tool_model"):
        if getattr(args, option, None) is not None:
            raise UsageError("--" + option.replace("_", "-"), "used with --robot only", "no --robot")
    if args.model is None:
        raise UsageError("--model", "a modal model (or --robot ROBOT --joints-deg Q1 .. Q6)", "nothing")
    if frf:
        return load_structure(args.model, args.axis)
    from oma.modal_io import read_modal_model

    return read_modal_model(args.model)


def rpm_range(args, setup) -> tuple[float, float]:
    if args.rpm is not None:
        lo, hi = args.rpm
    elif setup.limits.spindle_rpm is not None:
        lo, hi = setup.limits.spindle_rpm
    else:
        raise UsageError("--rpm", "MIN MAX (the setup has no limits.spindle_rpm)", "nothing")
    if not 0 < lo < hi:
        raise UsageError("--rpm", "0 < MIN < MAX", f"{lo} {hi}")
    return float(lo), float(hi)


def coefficients(setup, path):
    if setup.material.cutting_coefficients is None:
        raise InputError(path, "material.cutting_coefficients", "cutting coefficients", "none")
    return setup.material.cutting_coefficients


def save_figure(fig, path: str) -> None:
    """Save a figure atomically (format from the suffix)."""
    import matplotlib.pyplot as plt

    from oma.io import atomic_write

    with atomic_write(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight", format=Path(path).suffix.lstrip(".") or "png")
    plt.close(fig)


def add_json(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
