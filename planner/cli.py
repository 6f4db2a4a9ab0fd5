"""The ``robomill`` command line (cli.md): parse, call the library, print.

Exit codes: 0 done; 1 done with a negative answer; 2 bad input (one line on stderr, no traceback);
3 internal failure. With ``--json`` exactly one JSON object goes to standard output; everything else
(human text, progress, warnings) goes to standard error.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import warnings
from dataclasses import replace
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from oma.errors import InputError
from planner.report import jsonable

__all__ = ["main", "UsageError"]

EXIT_OK, EXIT_NEGATIVE, EXIT_INPUT, EXIT_INTERNAL = 0, 1, 2, 3


class UsageError(InputError):
    """A command-line argument that does not make sense (exit code 2)."""

    def __init__(self, option: str, expected: str, found: str):
        super().__init__(None, option, expected, found)

    def __str__(self) -> str:
        return f"{self.field}: expected {self.expected}, found {self.found}"


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors in one line and exit code 2, without printing usage."""

    def error(self, message):  # noqa: D401 - argparse API
        self.exit(EXIT_INPUT, f"robomill: {message} (see 'robomill --help')\n")


def _emit(args, payload: dict, human: Callable[[dict], str] | str) -> None:
    """Print the JSON object (``--json``) or the human summary (stdout)."""
    if args.json:
        sys.stdout.write(json.dumps(jsonable(payload), indent=None) + "\n")
    else:
        text = human(payload) if callable(human) else human
        sys.stdout.write(text.rstrip("\n") + "\n")


# --------------------------------------------------------------------------------------- handlers
# Each handler returns an exit code. Library imports happen inside, so `robomill --help` is fast.


def _load_structure(path: str, axis: str | None = None):
    """A modal model (YAML) or a measured FRF (CSV, UFF58, .frf) from a path."""
    from oma.frf_io import read_frf
    from oma.modal_io import read_modal_model

    suffix = Path(path).suffix.lower()
    if suffix in (".yaml", ".yml"):
        return read_modal_model(path)
    if suffix in (".csv", ".uff", ".unv", ".frf"):
        return read_frf(path, axis=axis)
    raise UsageError("--model", "a modal model (.yaml) or an FRF file (.csv, .uff, .frf)", repr(path))


def _cmd_simulate(args) -> int:
    from stability.setup_io import read_setup
    from oma.modal_io import read_modal_model
    from oma.record_io import write_record
    from stability.simulate import BackgroundForce, SensorModel, simulate

    setup = read_setup(args.setup)
    model = read_modal_model(args.model)
    if setup.material.cutting_coefficients is None:
        raise InputError(args.setup, "material.cutting_coefficients", "cutting coefficients to simulate with", "none")
    for option, value in (("--rpm", args.rpm), ("--depth", args.depth), ("--duration", args.duration),
                          ("--sample-rate", args.sample_rate)):
        if not value > 0:
            raise UsageError(option, "a positive number", repr(value))
    background = None
    if args.background_variance is not None:
        if any(v < 0 for v in args.background_variance):
            raise UsageError("--background-variance", "three variances >= 0 (N^2)", repr(args.background_variance))
        background = BackgroundForce(variance_N2=tuple(args.background_variance), bandwidth_hz=args.background_bandwidth)
    cut = replace(setup.cut, spindle_rpm=args.rpm, axial_depth_m=args.depth)
    sensors = SensorModel(
        force_noise_variance_N2=args.force_noise_variance,
        displacement_resolution_m=args.displacement_resolution,
    )
    result = simulate(
        model, setup.tool, cut, setup.material.cutting_coefficients,
        duration_s=args.duration, sample_rate_hz=args.sample_rate, background=background,
        sensors=sensors, seed=args.seed, progress=not args.json,
    )
    record = result.to_record(setup.tool, cut, material=setup.material, name=Path(args.output).name,
                              joints_deg=model.joints_deg)
    write_record(record, args.output)
    payload = {"record": str(Path(args.output))}
    _emit(args, payload, lambda p: f"record written to {p['record']}")
    return EXIT_OK


def _cmd_demo(args) -> int:
    from planner.demo import run_demo

    kwargs = {} if args.example is None else {"example_dir": Path(args.example)}
    summary = run_demo(Path(args.output), progress=not args.json, **kwargs)
    _emit(args, summary, lambda p: f"report: {p['report']}")
    return EXIT_OK


# ----------------------------------------------------------------------------------------- parser


def _add_json(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="robomill", description="Robotic milling: identify, predict, plan, check.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log diagnostics to stderr")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("simulate", help="time-domain simulation of a cut, written as a record")
    p.add_argument("setup")
    p.add_argument("--model", required=True)
    p.add_argument("--rpm", type=float, required=True)
    p.add_argument("--depth", type=float, required=True, help="axial depth of cut, m")
    p.add_argument("--duration", type=float, required=True, help="s")
    p.add_argument("-o", "--output", required=True, help="record directory to write")
    p.add_argument("--sample-rate", type=float, default=1000.0, help="record sample rate, Hz (default 1000)")
    p.add_argument("--seed", type=int, default=None, help="random seed (noise, background force)")
    p.add_argument("--background-variance", type=float, nargs=3, metavar=("VX", "VY", "VZ"), default=None,
                   help="broadband background force variance per machine axis, N^2 (default none)")
    p.add_argument("--background-bandwidth", type=float, default=200.0, help="Hz (default 200)")
    p.add_argument("--force-noise-variance", type=float, default=0.56, help="force sensor noise, N^2 (default 0.56)")
    p.add_argument("--displacement-resolution", type=float, default=1.5e-5,
                   help="displacement sensor resolution, m (default 1.5e-5, a laser tracker)")
    _add_json(p)
    p.set_defaults(handler=_cmd_simulate)

    p = sub.add_parser("demo", help="the whole job on the bundled example")
    p.add_argument("-o", "--output", default="out", help="output directory (default out/)")
    p.add_argument("--example", default=None, help="example cell directory (default: the bundled one)")
    _add_json(p)
    p.set_defaults(handler=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (cli.md)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return int(exc.code or 0)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr,
                        format="robomill: %(message)s")
    # Warnings are for people: one line each on stderr, never on stdout.
    warnings.showwarning = lambda message, category, *a, **k: sys.stderr.write(f"robomill: warning: {message}\n")
    try:
        return int(args.handler(args))
    except InputError as exc:
        sys.stderr.write(f"robomill: {exc}\n")
        return EXIT_INPUT
    except KeyboardInterrupt:
        sys.stderr.write("robomill: interrupted\n")
        return EXIT_INTERNAL
    except Exception as exc:  # an internal failure: say what, without a traceback unless -v
        if args.verbose:
            logging.exception("internal failure")
        sys.stderr.write(f"robomill: internal error: {type(exc).__name__}: {exc}\n")
        return EXIT_INTERNAL


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
