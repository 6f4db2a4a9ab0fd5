"""``robomill learn``: the posterior of the tool-tip modes and cutting coefficients from test cuts.

Registered through :data:`planner.cli.COMMAND_GROUPS`. Parses, validates every input before any
computation (bad input: exit 2, one line, nothing written), calls :func:`planner.learn.update.learn`,
prints.
"""

from __future__ import annotations

import functools
import math
import time
import warnings

from planner.cli_common import EXIT_OK, UsageError, add_json, declare_outputs, emit, finite, save_figure

__all__ = ["add_parsers", "parse_prior_sd", "chance_constraint", "posterior_lobes"]

_GROUPS = ("frequency", "stiffness", "damping", "coefficients")


def parse_prior_sd(items):
    """``['frequency=0.1', ...]`` -> :class:`PriorSD` (cli.md defaults for groups not given)."""
    from .posterior import PriorSD

    values = {}
    for item in items or []:
        name, sep, text = item.partition("=")
        if not sep or name not in _GROUPS:
            raise UsageError("--prior-sd", f"GROUP=VALUE with GROUP one of {', '.join(_GROUPS)}", repr(item))
        try:
            v = float(text)
        except ValueError:
            raise UsageError("--prior-sd", "a number after '='", repr(item)) from None
        if not (0 <= v <= 3):
            raise UsageError("--prior-sd", "a relative sd in [0, 3]", repr(item))
        values[name] = v
    return PriorSD(**values)


def add_parsers(sub) -> None:
    p = sub.add_parser("learn", help="Bayesian update of the stability model from test-cut outcomes")
    p.add_argument("setup", help="robomill-setup/1 file (tool, cutting frame, prior cutting coefficients)")
    p.add_argument("--model", required=True, help="prior robomill-modal/1 model")
    p.add_argument("--cuts", required=True, help="cut-outcomes CSV (formats.md)")
    p.add_argument("--predict", default=None, help="cuts CSV whose probability of stability to report")
    p.add_argument("--suggest", type=int, default=None, metavar="N", help="the N test cuts that would teach most")
    p.add_argument("--suggest-for", choices=["mrr", "boundary"], default="mrr",
                   help="what the suggested cuts teach about: the best stable removal rate (default) or the "
                        "stability boundary over the whole speed range")
    p.add_argument("-o", "--output", default=None, help="posterior model to write (MAP + x_posterior samples)")
    p.add_argument("--plot", default=None, metavar="FIG", help="lobes with 5/50/95 %% probability contours")
    p.add_argument("--prior-sd", nargs="+", default=None, metavar="GROUP=SD",
                   help="relative prior sds: frequency=0.10 stiffness=0.30 damping=0.50 coefficients=0.25")
    p.add_argument("--method", choices=["sdm", "auto", "zoa"], default="sdm",
                   help="stability method per cut (auto: SDM below ae/D = 0.2, ZOA above)")
    p.add_argument("--mislabel", type=finite, default=0.05, metavar="RATE",
                   help="share of wrong marks (default 0.05; the prior median of a learned share)")
    p.add_argument("--mislabel-sd", type=finite, default=None, metavar="SD",
                   help="prior sd of the learned share's log-odds (default 1.2: 90 %% between 0.7 and 22 %%); "
                        "given alone, > 0 learns the share (as --mislabel-model learned) and 0 fixes it")
    p.add_argument("--noisy-mislabel", type=finite, default=0.15, metavar="RATE",
                   help="averaged share (--mislabel-model average): the median of the learned share's prior, the "
                        "alternative to a fixed --mislabel (default 0.15: 90 %% of it between 2.8 %% and 38 %%)")
    p.add_argument("--mislabel-model", choices=["fixed", "learned", "average"], default=None,
                   help="the share of wrong marks fixed at --mislabel, learned, or both averaged by their evidence "
                        "(default: average; learned when only --mislabel-sd > 0 is given; fixed with --mislabel 0)")
    p.add_argument("--detection-lag", type=finite, default=None, metavar="LOG",
                   help="outcomes detected from records: how far (log depth ratio) beyond the limit half of "
                        "the chattering cuts are detected (default 0.22, measured on robomill's detection; 0 "
                        "with --detection-scale 0.03 treats them as marks)")
    p.add_argument("--detection-scale", type=finite, default=None, metavar="LOG",
                   help="width (log depth ratio) of the detected outcomes' soft boundary (default 0.11)")
    p.add_argument("--mode-correlation", type=finite, default=1.0, metavar="RHO",
                   help="several modes: correlation of the modes' prior factors within a group (1, the default: "
                        "one factor moves them all; below 1 each mode's own deviation is integrated out, "
                        "widening the boundary and each mode's sd)")
    p.add_argument("--samples", type=int, default=2000, help="posterior particles")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rpm", nargs=2, type=finite, default=None, metavar=("MIN", "MAX"),
                   help="speed range of --plot/--suggest (default: the setup's limits, else the cuts' range)")
    p.add_argument("--flute-length", type=finite, default=None, help="flute length, m: deeper cuts are rejected")
    add_json(p)
    declare_outputs(p, ("-o", "output", "file"), ("--plot", "plot", "figure"))
    p.set_defaults(handler=_cmd_learn)


def _speed_range(args, setup, cuts):
    if args.rpm is not None:
        lo, hi = args.rpm
        if not 0 < lo < hi:
            raise UsageError("--rpm", "0 < MIN < MAX", f"{lo} {hi}")
        return float(lo), float(hi)
    if setup.limits.spindle_rpm is not None:
        return tuple(float(x) for x in setup.limits.spindle_rpm)
    lo, hi = float(cuts.spindle_rpm.min()), float(cuts.spindle_rpm.max())
    return 0.8 * lo, 1.2 * hi


def _likelihood(args):
    """The outcome likelihood of ``--mislabel``, ``--mislabel-sd``, ``--mislabel-model``,
    ``--detection-lag``, ``--detection-scale``."""
    from .likelihood import DETECTION_LAG, DETECTION_SCALE, LEARNED_MISLABEL_SD, Likelihood

    lag = DETECTION_LAG if args.detection_lag is None else args.detection_lag
    width = DETECTION_SCALE if args.detection_scale is None else args.detection_scale
    if not 0 <= lag < 1:
        raise UsageError("--detection-lag", "a log depth ratio in [0, 1)", str(args.detection_lag))
    if not 0 < width < 1:
        raise UsageError("--detection-scale", "a log depth ratio in (0, 1)", str(args.detection_scale))

    # default: averaged (the marks of real shops are noisier than any one fixed rate; on the
    # benchmark's clean marks averaging cost 1 point of boundary error, docs/learn.md), learned
    # when only --mislabel-sd is given (> 0: learned, 0: fixed, as before), fixed when there are
    # no wrong marks
    if args.mislabel_model:
        mode = args.mislabel_model
    elif args.mislabel_sd is not None:
        mode = "learned" if args.mislabel_sd > 0 else "fixed"
    else:
        mode = "fixed" if args.mislabel == 0 else "average"
    sd = LEARNED_MISLABEL_SD if args.mislabel_sd is None else args.mislabel_sd
    if mode != "fixed" and not (sd > 0 and args.mislabel > 0):
        raise UsageError("--mislabel-model", f"--mislabel > 0 and --mislabel-sd > 0 to learn the share ({mode})",
                         f"--mislabel {args.mislabel:g} --mislabel-sd {sd:g}")
    return Likelihood(mislabel=args.mislabel, mislabel_sd=0.0 if mode == "fixed" else sd,
                      mislabel_average=mode == "average", noisy_mislabel=args.noisy_mislabel, detection_lag=lag,
                      detection_scale=width)


def _cmd_learn(args) -> int:
    from oma._fields import FileWarning
    from oma.errors import InputError
    from oma.modal_io import read_modal_model
    from stability.setup_io import read_setup

    from .outcomes_io import expected_chatter_frequency, read_cuts
    from .posterior_io import MAX_WRITTEN_SAMPLES, write_posterior_model
    from .predictive import checked_predictions, probability_lobes
    from .speed_range import lobes_for_improvement
    from .suggest import MIN_SPEED_GAP, allowed_depths, suggest_cuts
    from .update import learn

    started = time.perf_counter()

    # ---- every input read and checked before anything is computed or written
    setup = read_setup(args.setup)
    if setup.material.cutting_coefficients is None:  # read_setup requires them; kept explicit
        raise InputError(args.setup, "material.cutting_coefficients", "the prior cutting coefficients", "none")
    prior = read_modal_model(args.model)
    prior_sd = parse_prior_sd(args.prior_sd)
    if not 0 <= args.mislabel < 0.5:
        raise UsageError("--mislabel", "a share in [0, 0.5)", str(args.mislabel))
    if not 0 < args.noisy_mislabel < 0.5:
        raise UsageError("--noisy-mislabel", "a share in (0, 0.5)", str(args.noisy_mislabel))
    if args.mislabel_sd is not None and not args.mislabel_sd >= 0:
        raise UsageError("--mislabel-sd", "a log-odds sd >= 0", str(args.mislabel_sd))
    likelihood = _likelihood(args)
    if not 0.0 <= args.mode_correlation <= 1.0:
        raise UsageError("--mode-correlation", "a correlation in [0, 1]", str(args.mode_correlation))
    if args.samples < 100:
        raise UsageError("--samples", "at least 100", str(args.samples))
    if args.suggest is not None and not 1 <= args.suggest <= 100:
        raise UsageError("--suggest", "N in 1..100", str(args.suggest))
    if args.flute_length is not None and not args.flute_length > 0:
        raise UsageError("--flute-length", "a positive length in m", str(args.flute_length))
    max_depth = None if setup.limits.axial_depth_m is None else float(setup.limits.axial_depth_m[1])
    with warnings.catch_warnings(record=True) as seen:  # the table's warnings go into the report
        warnings.simplefilter("always", FileWarning)
        # a detected "stable" whose record cannot show the chatter the prior expects weighs 0.1
        cuts = read_cuts(args.cuts, tool=setup.tool, flute_length_m=args.flute_length, max_depth_m=max_depth,
                         chatter_frequency=functools.partial(expected_chatter_frequency, prior, setup))
    input_warnings = [str(w.message) for w in seen if issubclass(w.category, FileWarning)]
    for w in seen:
        if not issubclass(w.category, FileWarning):
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    to_predict = None
    if args.predict:
        to_predict = read_cuts(args.predict, tool=setup.tool, outcomes_required=False,
                               flute_length_m=args.flute_length)
    rpm_range = _speed_range(args, setup, cuts)

    result = learn(setup, prior, cuts, prior_sd=prior_sd, n_particles=args.samples, seed=args.seed,
                   method=args.method, likelihood=likelihood, mode_correlation=args.mode_correlation)
    post = result.posterior
    payload = result.to_dict()
    payload["warnings"] = input_warnings + payload["warnings"]
    payload["n_cuts"] = int(cuts.n_cuts)
    payload["predictions"] = None
    payload["predictions_table_error"] = None
    payload["suggested"] = None
    timings = payload["timings_s"] = dict(payload["timings_s"], learn=payload["timings_s"]["total"])
    t0 = time.perf_counter()
    if to_predict is not None:
        p, err = checked_predictions(post, setup, to_predict, method=args.method)
        payload["predictions"] = [{"index": i, "probability_stable": float(x)} for i, x in enumerate(p)]
        payload["predictions_table_error"] = err
        timings["predict"] = time.perf_counter() - t0
    lobes, speeds = None, None
    t0 = time.perf_counter()
    if args.suggest and args.suggest_for == "mrr" and not args.plot:
        # only the speeds where a test cut could beat the best proven-stable one (docs/learn.md)
        lobes, speeds = lobes_for_improvement(post, setup, rpm_range, method=args.method)
    elif args.suggest or args.plot:
        lobes = probability_lobes(post, setup, rpm_range, method=args.method)
    if lobes is not None:
        timings["lobes"] = time.perf_counter() - t0
    if args.suggest:
        t0 = time.perf_counter()
        # the next cuts are assumed judged the way most of these were (marks, or detected from records)
        marked = cuts.outcome >= 0
        detected = 2 * int((cuts.detected & marked).sum()) > int(marked.sum())

        def pick(lobes):
            # only cuts the setup's limits allow (speed, depth, power, torque, force: docs/learn.md)
            least, most, within = allowed_depths(setup, lobes.rpm, post.reference)
            return within, *suggest_cuts(lobes, args.suggest, criterion=args.suggest_for, likelihood=post.likelihood,
                                         detected=detected, allowed_depth_m=(least, most))

        within, sugg, gain, incumbent = pick(lobes)
        if speeds is not None and speeds.restricted and (sugg.n_cuts < args.suggest
                                                          or not all(g > 0 for g in gain)):
            # fewer cuts with an expected improvement than asked: the whole range adds some at its lowest speeds
            lobes, speeds = probability_lobes(post, setup, rpm_range, method=args.method), None
            within, sugg, gain, incumbent = pick(lobes)
        if speeds is not None:
            payload["suggested_rpm_range"] = list(speeds.rpm_range)
            payload["suggested_rpm_range_note"] = speeds.note()
        timings["suggest"] = time.perf_counter() - t0
        payload["suggested_outcomes"] = "detected" if detected else "marked"
        payload["suggested_within"] = list(within)
        fz = setup.cut.feed_per_tooth_m
        scale = setup.cut.radial_depth_m * fz * setup.tool.teeth / 60.0
        payload["suggested"] = suggested_rows(sugg, gain, args.suggest_for, feed_per_tooth_m=fz, mrr_per_unit=scale)
        if sugg.n_cuts < args.suggest:
            payload["warnings"].append(
                f"{sugg.n_cuts} test cut(s) suggested, not {args.suggest}: the setup's limits ({', '.join(within)}) "
                f"allow no more speeds {MIN_SPEED_GAP:.0%} apart in the range")
        payload["best_stable_mrr_m3_s"] = incumbent * scale
    # the posterior's samples (--predict uses them all, --plot and --suggest at most 400) and, with
    # -o, the samples written (at most MAX_WRITTEN_SAMPLES of them, the MAP first)
    payload["posterior_samples"] = int(post.samples.shape[0])
    if args.output:
        payload["posterior_samples_written"] = min(int(post.samples.shape[0]), MAX_WRITTEN_SAMPLES)
    # each mark's posterior probability of being wrong: the figure greys the stable marks it doubts,
    # and a suspect stable mark backs no planned cut (:mod:`.support`)
    wrong = result.mislabel_probability if result.mislabel_probability.shape == (cuts.n_cuts,) else None
    # ---- outputs last, each atomically
    if args.plot:
        fig, _ = lobes.plot(cuts=cuts, mislabelled=wrong)
        save_figure(fig, args.plot)
    if args.output:
        # with the cuts, which ``plan`` compares its cut with
        marked = cuts.outcome >= 0
        payload["posterior"] = str(write_posterior_model(post, args.output, cuts=cuts.take(marked),
                                                         mislabelled=None if wrong is None else wrong[marked]))
    timings["total"] = time.perf_counter() - started
    emit(args, payload, lambda d: _human(d, result))
    return EXIT_OK


def suggested_rows(cuts, score, criterion: str, *, feed_per_tooth_m: float, mrr_per_unit: float) -> list[dict]:
    """The suggested cuts as rows of a cut-outcomes table (formats.md): the cut, the setup's feed,
    an empty outcome, and the score under the ``x_`` prefix of extensions (so that a row saved as
    CSV reads back): ``x_expected_improvement_mrr_m3_s`` (``mrr``; ``score`` in m rpm times
    ``mrr_per_unit``) or ``x_expected_variance_reduction`` (``boundary``)."""
    out = []
    for i, g in enumerate(score):
        extra = ({"x_expected_improvement_mrr_m3_s": float(g * mrr_per_unit)} if criterion == "mrr"
                 else {"x_expected_variance_reduction": float(g)})
        out.append(dict(cuts.row(i), feed_per_tooth_m=feed_per_tooth_m, **extra))
    return out


def _human(d, result) -> str:
    lines = [f"learned from the test cuts: cross-validated accuracy {d['accuracy_before']:.2f} (prior) -> "
             f"{d['accuracy_after']:.2f} (posterior); moved most: {d['cause']}"]
    for name, s in d["parameters"].items():
        if not s["fixed"]:
            lines.append(f"  {name:24s} {s['prior']:.4g} +- {s['prior_sd']:.2g}  ->  {s['mean']:.4g} +- {s['sd']:.2g}")
    for w in d["warnings"]:
        lines.append(f"warning: {w}")
    if d.get("predictions"):
        lines.append("P(stable) of the cuts to predict: " + ", ".join(f"{x['probability_stable']:.2f}"
                                                                      for x in d["predictions"][:20]))
    if d.get("suggested"):
        lines.append("next test cuts (rpm, axial depth mm): " + "; ".join(
            f"{s['spindle_rpm']:.0f}, {1e3 * s['axial_depth_m']:.2f}" for s in d["suggested"]))
    if d.get("posterior"):
        lines.append(f"posterior model: {d['posterior']}")
    return "\n".join(lines)


# ------------------------------------------------------------- used by `plan` and `lobes` (planner.cli)
def verify_plan(limit, learned: dict, rpm: float, axial_depth_m: float) -> None:
    """For ``plan``: the planned cut's P(stable) from posterior samples solved directly at its speed
    (``learned['check']``) and a warning when it falls short of the level."""
    check = limit.verify(rpm, axial_depth_m)
    learned["check"] = check
    if not check["holds"]:
        learned.setdefault("warnings", []).append(
            f"the planned cut is stable with P = {check['probability_stable']:.3f} (+- {check['standard_error']:.3f}) "
            f"when {check['samples']} posterior samples are solved directly at {rpm:.0f} rpm, below the level "
            f"{limit.probability:g} the limit table gave: plan a lower depth or check the cut")


def report_support(learned: dict, tests, setup, structure, planned: dict, *, method: str = "auto") -> None:
    """For ``plan``: what the test cuts the posterior was learned from (``tests``, the
    :class:`.posterior_io.PosteriorCuts` from :func:`chance_constraint`; None when its file does not
    carry them) say about the planned cut (``planned``: the plan's JSON) at the setup's engagement:
    ``learned['support']`` (:mod:`.support`) and a warning unless one of them backs it. Where none
    does, ``support['best_backed']`` is the best plan the stable cuts prove (:func:`.support.best_backed`,
    with ``structure`` for the other limits; its ``share_of_plan`` of the plan's removal rate, and a
    warning where it removes more than the plan: the posterior then doubts it).

    A stable mark counts when the posterior's probability that it is wrong is at most one minus the
    plan's level (``support['max_doubt']``, 0.05 at P >= 0.95): what a mark proves is trusted as far
    as the plan's own probability is."""
    from .support import best_backed, doubt_level, plan_support, support_warning

    if tests is None:
        learned["support"] = None
        learned.setdefault("warnings", []).append(
            "the posterior file does not carry the test cuts it was learned from (written by an earlier robomill): "
            "whether a test cut backs the plan is not known")
        return
    rpm, ap, cut = planned["spindle_rpm"], planned["axial_depth_m"], setup.cut
    doubt = doubt_level(learned["probability"])
    support = learned["support"] = plan_support(tests.cuts, rpm, ap, cut.radial_depth_m, cut.milling == "down",
                                                mislabelled=tests.mislabelled, max_doubt=doubt)
    support["max_doubt"] = doubt
    warnings_ = learned.setdefault("warnings", [])
    if support["status"] != "backed":
        t0 = time.perf_counter()
        alt = best_backed(setup, structure, tests.cuts, mislabelled=tests.mislabelled, max_doubt=doubt, method=method)
        learned.setdefault("timings_s", {})["best_backed"] = time.perf_counter() - t0
        if alt is not None:
            i = alt["backed_by"]
            wrong = float(tests.mislabelled[i])
            alt["share_of_plan"] = alt["mrr_m3_s"] / planned["mrr_m3_s"]
            alt["probability_mislabelled"] = wrong if math.isfinite(wrong) else None
            if alt["share_of_plan"] > 1.0:
                warnings_.append(
                    f"the best cut a stable test cut proves ({alt['spindle_rpm']:.0f} rpm at "
                    f"{1e3 * alt['axial_depth_m']:.2f} mm) removes {100 * alt['share_of_plan']:.0f} % of the plan's "
                    "rate: "
                    f"the posterior gives it P(stable) under {learned['probability']:g}, so it rests on cut {i}'s mark "
                    "alone; cut it again before relying on it")
        support["best_backed"] = alt
    text = support_warning(support, tests.cuts, rpm, ap)
    if text:
        warnings_.append(text)


def chance_constraint(model_path, setup, *, probability: float = 0.95):
    """For ``plan``: ``(stability_limit, learned, tests)`` when the model carries ``x_posterior``
    (the depth stable with ``probability``, what was learned, for the report, and the test cuts
    its file carries, read before anything is computed: :func:`report_support`), else
    ``(None, None, None)``.

    The limit is tabulated only over the speeds where a cut could beat the best plan
    (:func:`planner.learn.speed_range.chance_limit_for_plan`, planning on the part of the range
    with the model of ``model_path``, the structure ``plan`` reads); ``learned`` says which
    (``rpm_range``, ``rpm_range_note``) and how long the table, its check and those plans took
    (``timings_s``)."""
    from oma.errors import SetupError
    from oma.modal_io import read_modal_model
    from planner.plan_results import plan_bounds

    from .posterior_io import read_posterior, read_posterior_cuts
    from .speed_range import chance_limit_for_plan

    if not 0 < probability < 1:
        raise UsageError("--probability", "a probability in (0, 1)", repr(probability))
    post = read_posterior(model_path)
    if post is None or setup.limits.spindle_rpm is None:
        return None, None, None
    try:
        plan_bounds(setup)
    except SetupError:  # plan raises it, naming the setup file
        return None, None, None
    tests = read_posterior_cuts(model_path)
    limit, speeds = chance_limit_for_plan(post, read_modal_model(model_path), setup, probability=probability)
    learned = {"probability": float(probability), "samples": int(post.samples.shape[0]),
               "method": post.method, "cause": post.cause(), "parameters": post.parameters(),
               "table_error": limit.table_error, "boundary_width": limit.boundary_width,
               "note": f"stability: P(stable) >= {probability:g} under the posterior learned from test cuts, "
                       "the forward model's error included (the chance constraint replaces the stability margin)",
               **speeds.to_dict()}
    return limit, learned, tests


def posterior_lobes(model_path, setup, rpm_range):
    """For ``lobes``: the probability lobes and the test cuts the file carries
    (:class:`.posterior_io.PosteriorCuts`; None without) when the model carries ``x_posterior``,
    else ``(None, None)``."""
    from pathlib import Path

    from .posterior_io import read_posterior, read_posterior_cuts
    from .predictive import probability_lobes

    if len(model_path) != 1 or Path(model_path[0]).suffix.lower() not in (".yaml", ".yml"):
        return None, None
    post = read_posterior(model_path[0])
    if post is None:
        return None, None
    tests = read_posterior_cuts(model_path[0])  # read before the lobes are computed
    return probability_lobes(post, setup, rpm_range), tests
