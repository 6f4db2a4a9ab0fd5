"""cli.md's contract on the inputs an audit (session 14) found handled wrongly: each was exit 3
("internal error") after the whole computation, silently wrong, or named no file. Now: exit 2,
one line on stderr naming the file or option, before any work, and no output file written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.cli import main

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "kr500_acetal"
SETUP = str(EXAMPLE / "setup.yaml")
MODEL = str(EXAMPLE / "models" / "planning_model.yaml")
POSES = sorted(str(p) for p in (EXAMPLE / "poses").glob("pose_*.yaml"))


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("name, kind_found", [("fig.xyz", "ending in ."), ("", "an existing directory")])
def test_a_bad_figure_path_is_exit_2_before_planning(capsys, tmp_path, name, kind_found):
    target = tmp_path / name
    code, out, err = _run(capsys, "plan", SETUP, "--model", MODEL, "-o", target, "--json")
    assert code == 2 and out == "" and kind_found in _one_line(err) and "-o" in err
    assert sorted(tmp_path.iterdir()) == []


def test_an_output_below_a_file_or_a_directory_over_a_file_is_exit_2(capsys, tmp_path):
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    code, _, err = _run(capsys, "identify", EXAMPLE / "records" / "cut_short", "-o", blocker / "m.yaml")
    assert code == 2 and "is a file" in _one_line(err)
    code, _, err = _run(capsys, "simulate", SETUP, "--model", MODEL, "--rpm", 3000, "--depth", 1e-3,
                        "--duration", 0.1, "-o", blocker)
    assert code == 2 and "an existing file" in _one_line(err)
    assert blocker.read_text() == "x"


@pytest.mark.parametrize("argv", [
    ["predict", SETUP, "--model", MODEL, "--rpm", "inf", "--depth", "0.001"],
    ["predict", SETUP, "--model", MODEL, "--rpm", "4000", "--depth", "nan"],
    ["lobes", SETUP, "--model", MODEL, "--rpm", "4000", "inf"],
    ["lobes", SETUP, "--model", MODEL, "--n-rpm", "1"],
    ["lobes", SETUP, "--model", str(EXAMPLE / "records" / "cut_long" / "reference_frf.csv"), "--method", "sdm"],
])
def test_non_finite_numbers_and_impossible_options_are_exit_2(capsys, argv):
    code, out, err = _run(capsys, *argv)
    assert code == 2 and out == ""
    _one_line(err)


def test_plan_errors_on_the_setup_name_the_setup_file(capsys, tmp_path):
    doc = yaml.safe_load((EXAMPLE / "setup.yaml").read_text())
    doc["limits"]["spindle_rpm"] = [3000, 3000]
    bad = tmp_path / "rpm_eq.yaml"
    bad.write_text(yaml.safe_dump(doc))
    code, _, err = _run(capsys, "plan", bad, "--model", MODEL)
    assert code == 2 and _one_line(err).startswith(f"robomill: {bad}: limits.spindle_rpm:")


def test_check_with_models_refuses_what_it_would_ignore_or_fail_on(capsys, tmp_path):
    toolpath = EXAMPLE / "toolpath.yaml"
    # a tool model is added to a robot's modes; with --models it was silently ignored
    code, _, err = _run(capsys, "check", toolpath, "--models", *POSES, "--tool-model", EXAMPLE / "models" / "tool_mode.yaml")
    assert code == 2 and "--tool-model" in _one_line(err)
    # two models at one pose: the file of the second is named (it was an internal error)
    twin = tmp_path / "pose_1_copy.yaml"
    shutil.copy(POSES[0], twin)
    code, _, err = _run(capsys, "check", toolpath, "--models", POSES[0], twin, *POSES[1:])
    line = _one_line(err)
    assert code == 2 and line.startswith(f"robomill: {twin}: pose.joints_deg:") and POSES[0] in line
    # a model without a pose: its file, not "<input>: models[0]"
    code, _, err = _run(capsys, "check", toolpath, "--models", EXAMPLE / "models" / "tool_mode.yaml", *POSES)
    assert code == 2 and "tool_mode.yaml: pose.joints_deg" in _one_line(err) and "<input>" not in err
    # a toolpath without joint angles cannot be checked against models at poses
    doc = yaml.safe_load(toolpath.read_text())
    import csv

    rows = list(csv.DictReader((EXAMPLE / doc["points"]).open()))
    keep = [c for c in rows[0] if not c.startswith("q")]
    with (tmp_path / "nojoints.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, keep)
        w.writeheader()
        w.writerows({c: r[c] for c in keep} for r in rows)
    doc["points"] = "nojoints.csv"
    doc["robot"] = str(EXAMPLE / doc["robot"])  # a toolpath with a robot may leave the joints out
    (tmp_path / "nojoints.yaml").write_text(yaml.safe_dump(doc))
    code, _, err = _run(capsys, "check", tmp_path / "nojoints.yaml", "--models", *POSES)
    assert code == 2 and "q1_deg..q6_deg" in _one_line(err)


def test_output_only_json_carries_the_identify_keys_and_honours_the_band(capsys):
    code, out, _ = _run(capsys, "identify", EXAMPLE / "records" / "cut_long", "--output-only", "--band", 4, 60,
                        "--json")
    payload = json.loads(out)
    assert payload["band_hz"] == [4.0, 60.0]
    assert all(4.0 <= m["natural_frequency_hz"] <= 60.0 for m in payload["modes"])
    for key in ("frf_fit_error", "noise_variance_N2", "min_noise_variance_N2", "excitation_sufficient"):
        assert key in payload and payload[key] is None  # no force-based fit behind the output-only model
        assert key in payload["force_based"]            # the records have force: that fit's values
    assert np.isfinite(payload["force_based"]["noise_variance_N2"]["X"])
