"""The command line, in process (``main([...])``): exit codes, one-line errors, JSON on stdout."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
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


EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "kr500_acetal"


def test_simulate_of_a_diverging_cut_is_exit_2_naming_the_depth(capsys, tmp_path):
    code, out, err = _run(
        capsys, "simulate", str(EXAMPLE / "setup.yaml"), "--model", str(EXAMPLE / "models" / "tool_mode.yaml"),
        "--rpm", "3000", "--depth", "0.5", "--duration", "2", "-o", str(tmp_path / "rec"), "--json",
    )
    assert code == 2 and out == ""
    assert err.startswith("robomill: --depth:") and "diverged" in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "rec").exists()


def test_lobes_json_has_matching_lists_and_writes_the_figure(capsys, tmp_path):
    fig = tmp_path / "lobes.png"
    code, out, err = _run(capsys, "lobes", str(EXAMPLE / "setup.yaml"), "--model",
                          str(EXAMPLE / "models" / "planning_model.yaml"), "--rpm", "2000", "6000",
                          "-o", str(fig), "--json")
    assert code == 0, err
    payload = json.loads(out)
    assert payload["method"] == "zoa"
    assert len(payload["rpm"]) == len(payload["depth_limit_m"]) > 10
    assert min(payload["rpm"]) >= 2000 and max(payload["rpm"]) <= 6000
    assert fig.stat().st_size > 1000


def test_predict_agrees_with_lobes_and_reports_the_cli_keys(capsys):
    args = [str(EXAMPLE / "setup.yaml"), "--model", str(EXAMPLE / "models" / "planning_model.yaml")]
    code, out, _ = _run(capsys, "lobes", *args, "--rpm", "2600", "2800", "--json")
    lobes = json.loads(out)
    limit = float(np.interp(2700.0, lobes["rpm"], lobes["depth_limit_m"]))
    for factor, stable in ((0.9, True), (1.1, False)):
        code, out, err = _run(capsys, "predict", *args, "--rpm", "2700", "--depth", str(factor * limit), "--json")
        assert code == 0, err
        p = json.loads(out)
        assert {"stable", "depth_limit_m", "surface_location_error_m", "peak_force_N", "mrr_m3_s"} <= set(p)
        assert p["stable"] is stable
        assert p["depth_limit_m"] == pytest.approx(limit, rel=1e-3)


def test_frf_model_needs_one_axis_per_frf_file(capsys, tmp_path):
    frf = tmp_path / "xx.frf"
    frf.write_text("freq re im\n10 1e-6 0\n20 1e-6 -1e-6\n")
    code, out, err = _run(capsys, "lobes", str(EXAMPLE / "setup.yaml"), "--model", str(frf), "--json")
    assert code == 2
    assert "--axis" in err and len(err.strip().splitlines()) == 1


def test_check_flags_the_examples_deep_stretch_and_exits_1(capsys):
    models = sorted(str(p) for p in (EXAMPLE / "poses").glob("pose_*.yaml"))
    code, out, err = _run(capsys, "check", str(EXAMPLE / "toolpath.yaml"), "--models", *models, "--json")
    assert code == 1, err  # violations: a negative answer
    payload = json.loads(out)
    kinds = {v["kind"] for v in payload["violations"]}
    assert payload["points"] == 240
    assert {"chatter", "pose_out_of_range"} <= kinds
    assert kinds <= {"chatter", "surface_error", "force", "power", "pose_out_of_range"}
    for v in payload["violations"]:
        assert {"index", "kind", "value", "limit"} <= set(v)


def test_identify_compares_with_the_hammer_test_and_writes_the_model(capsys, tmp_path):
    from oma.modal_io import read_modal_model

    rec = EXAMPLE / "records" / "cut_long"
    out_model = tmp_path / "robot.yaml"
    code, out, err = _run(capsys, "identify", str(rec), "--reference", str(rec / "reference_frf.csv"),
                          "-o", str(out_model), "--json")
    assert code == 0, err
    p = json.loads(out)
    assert {"model", "frf_fit_error", "noise_variance_N2", "min_noise_variance_N2", "excitation_sufficient",
            "warnings"} <= set(p)  # cli.md
    ra = p["reference_agreement"]
    assert ra["band_hz"] == [5.0, 40.0]
    # 20 s of cutting against a hammer test with 3 % noise: every direct FRF within 10 % (2-norm)
    assert all(ra[a] < 0.10 for a in "XYZ"), ra
    written = read_modal_model(out_model)
    np.testing.assert_allclose(written.natural_frequency_hz,
                               [m["natural_frequency_hz"] for m in p["model"]["modes"]], rtol=1e-12)


def test_identify_rejects_a_band_outside_the_reference_before_writing(capsys, tmp_path):
    rec = EXAMPLE / "records" / "cut_long"
    out_model = tmp_path / "robot.yaml"
    code, out, err = _run(capsys, "identify", str(rec), "--reference", str(rec / "reference_frf.csv"),
                          "--band", "100", "200", "-o", str(out_model))
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "--band" in err and "2-60 Hz" in err
    assert not out_model.exists()


def test_plan_reports_a_verified_optimum(capsys):
    code, out, err = _run(capsys, "plan", str(EXAMPLE / "setup.yaml"), "--model",
                          str(EXAMPLE / "models" / "planning_model.yaml"), "--json")
    assert code == 0, err
    p = json.loads(out)
    assert p["success"] is True
    assert p["mrr_m3_s"] == pytest.approx(
        p["axial_depth_m"] * 0.006 * p["feed_per_tooth_m"] * 2 * p["spindle_rpm"] / 60.0, rel=1e-9)
    # re-check the answer independently with predict at the recommended point
    code, out, _ = _run(capsys, "predict", str(EXAMPLE / "setup.yaml"), "--model",
                        str(EXAMPLE / "models" / "planning_model.yaml"), "--rpm", str(p["spindle_rpm"]),
                        "--depth", str(p["axial_depth_m"]), "--json")
    assert json.loads(out)["stable"] is True


def test_diagnose_names_the_record_file_that_is_too_short(capsys):
    # the 1.1 s record cannot be split into a fit and a validation half of 1 s each: a one-line
    # error that names the record's path, exit code 2
    short = str(EXAMPLE / "records" / "cut_short")
    code, out, err = _run(capsys, "diagnose", short, "--model", str(EXAMPLE / "truth" / "robot_at_cut.yaml"))
    assert code == 2 and out == ""
    assert err.strip().count("\n") == 0 and short in err and "found 1.1 s" in err, err


def test_diagnose_on_the_clean_example_names_no_cause(capsys):
    code, out, err = _run(capsys, "diagnose", str(EXAMPLE / "records" / "cut_long"), "--model",
                          str(EXAMPLE / "truth" / "robot_at_cut.yaml"), "--json")
    assert code == 0, err
    p = json.loads(out)
    assert {"cause", "parameters", "error_before", "error_after", "gain", "ranking"} <= set(p)
    assert p["cause"] == "none"  # simulated with exactly this model: nothing to explain
    assert {r["cause"] for r in p["ranking"]} == {"runout", "force_sensor_dynamics", "channel_delay",
                                                  "process_damping", "unmodeled_mode", "cross_coupling",
                                                  "pose_drift", "nonlinear_cutting", "cutting_coefficients"}


def test_diagnose_human_output_with_a_failed_fit_in_the_ranking(capsys):
    """A cause whose fit failed has no gain (JSON null): the human summary says n/a where it was an
    internal error (exit 3) with the figure already written (the session-14 audit: the planning
    model, whose 720 Hz tool modes the 1 kHz record cannot see, on the long example record)."""
    code, out, err = _run(capsys, "diagnose", str(EXAMPLE / "records" / "cut_long"), "--model",
                          str(EXAMPLE / "models" / "planning_model.yaml"))
    assert code == 0, err
    assert out.startswith("cause: ") and "ranking: " in out
