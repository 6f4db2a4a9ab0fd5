"""What every ``robomill`` subcommand shares (cli.md): exit codes, the one-line usage error, the
JSON-or-text output, atomic figure saving, and reading a structure (modal model or FRFs).

Command groups that live in their own sub-package (``planner.robot``, ...) register their parsers
through an ``add_parsers(sub)`` function and use these helpers; :mod:`planner.cli` wires them.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from oma.errors import InputError
from planner.report import jsonable

__all__ = ["EXIT_OK", "EXIT_NEGATIVE", "EXIT_INPUT", "EXIT_INTERNAL", "UsageError", "Parser", "emit",
           "add_json", "save_figure", "load_structure", "rpm_range", "coefficients", "add_model_options",
           "structure_from_args", "finite", "declare_outputs", "check_outputs", "naming_files"]

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


def finite(text: str) -> float:
    """argparse ``type`` of a number option: a finite float (``float`` alone takes ``inf`` and ``nan``,
    which then ran through the numerics: ``predict --rpm inf`` said "stable")."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, found {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, found {text!r}")
    return value


#: What an output option writes: a figure (its suffix picks the format), a file, or a directory.
OUTPUT_KINDS = ("figure", "file", "directory")


def declare_outputs(p: argparse.ArgumentParser, *outputs: tuple[str, str, str]) -> None:
    """Declare a subcommand's output options as ``(option, attribute, kind)``; :func:`check_outputs`
    checks them before the command computes anything."""
    assert all(kind in OUTPUT_KINDS for _, _, kind in outputs)
    p.set_defaults(outputs=tuple(outputs))


def _figure_suffixes() -> tuple[str, ...]:
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted(FigureCanvasBase.get_supported_filetypes()))


def check_outputs(args) -> None:
    """Every declared output path can be written as what it is, before any work is done: a figure
    with a format matplotlib writes, a file that is not a directory, a directory that is not a file,
    and no existing file where a folder on the way must be (the outputs' folders are created).
    Before this, a bad path failed after the whole computation, as an internal error (exit 3)."""
    for option, attribute, kind in getattr(args, "outputs", ()):
        value = getattr(args, attribute, None)
        if not value:
            continue
        path = Path(value)
        what = "a directory" if kind == "directory" else "a file path"
        if kind == "directory" and path.exists() and not path.is_dir():
            raise UsageError(option, what, f"{value} (an existing file)")
        if kind != "directory" and path.is_dir():
            raise UsageError(option, what, f"{value} (an existing directory)")
        blocked = next((a for a in path.parents if a.exists() and not a.is_dir()), None)
        if blocked is not None:
            raise UsageError(option, f"{what} in a folder", f"{value} ({blocked} is a file)")
        if kind == "figure":
            suffix = path.suffix.lower().lstrip(".")
            formats = _figure_suffixes()
            if suffix and suffix not in formats:
                raise UsageError(option, "a figure file ending in ." + ", .".join(formats), value)


@contextmanager
def naming_files(default, models: Sequence[str] = ()) -> Iterator[None]:
    """Errors raised on input the library was given in memory (``<input>``) name the file it came
    from: ``models[i]...`` the i-th of ``models``, anything else ``default`` (cli.md: "one line
    naming the file, the field and what was wrong")."""
    try:
        yield
    except InputError as exc:
        if exc.file is not None or isinstance(exc, UsageError):
            raise
        def named(text: str) -> str:  # "models[1]" in a message: that file's name
            return re.sub(r"models\[(\d+)\]", lambda k: models[int(k.group(1))] if int(k.group(1)) < len(models)
                          else k.group(0), text)

        expected, found = named(exc.expected), named(exc.found)
        m = re.match(r"models\[(\d+)\]\.?(.*)", exc.field)
        if m and int(m.group(1)) < len(models):
            raise type(exc)(models[int(m.group(1))], m.group(2) or "(the model)", expected, found) from None
        raise type(exc)(default, exc.field, expected, found) from None


def add_json(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
