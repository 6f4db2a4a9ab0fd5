"""robomill-modal/1: reading, writing, dict form, round trips and invalid files (formats.md)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml

from oma._fields import FileWarning
from oma.errors import ModelError
from oma.modal import ModalModel
from oma.modal_io import modal_model_from_dict, modal_model_to_dict, read_modal_model, write_modal_model


def edit(path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


def random_model(seed: int = 7, n_modes: int = 4) -> ModalModel:
    """Seeded model with oblique modes, a symmetric residual compliance, a pose and provenance."""
    rng = np.random.default_rng(seed)
    r = rng.normal(size=(3, 3)) * 1e-9
    return ModalModel(
        natural_frequency_hz=np.sort(rng.uniform(8.0, 60.0, n_modes)),
        damping_ratio=rng.uniform(0.02, 0.1, n_modes),
        stiffness_N_m=10 ** rng.uniform(5.5, 7.0, n_modes),
        directions=rng.normal(size=(n_modes, 3)),
        residual_compliance_m_N=r @ r.T / 1e-9,
        joints_deg=rng.uniform(-180, 180, 6),
        source={"method": "oma-h1", "records": ["a", "b"], "fit_error": np.float64(0.0312)},
    )


def assert_same_model(a: ModalModel, b: ModalModel) -> None:
    for name in ("natural_frequency_hz", "damping_ratio", "stiffness_N_m", "directions",
                 "residual_compliance_m_N"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    if a.joints_deg is None:
        assert b.joints_deg is None
    else:
        np.testing.assert_array_equal(a.joints_deg, b.joints_deg)


def test_read_example(valid_modal_file):
    m = read_modal_model(valid_modal_file)
    np.testing.assert_array_equal(m.natural_frequency_hz, [10.5, 24.8])
    np.testing.assert_array_equal(m.damping_ratio, [0.05, 0.04])
    np.testing.assert_array_equal(m.stiffness_N_m, [1.5e6, 3.0e6])
    np.testing.assert_array_equal(m.directions, np.eye(3)[:2])
    np.testing.assert_array_equal(np.diag(m.residual_compliance_m_N), [1e-9, 1e-9, 2e-9])
    np.testing.assert_array_equal(m.joints_deg, [88.44, -13.62, 72.42, 180.90, 59.55, -0.67])
    assert m.source == {"method": "oma-h1", "records": ["rec1"], "fit_error": 0.03}


def test_read_model_has_the_receptance_of_formats_md(valid_modal_file):
    # G_xx at resonance of mode 1 is 1/(k (2 i zeta)) + the other mode's (zero along X) + residual
    m = read_modal_model(valid_modal_file)
    g = m.receptance([10.5, 0.0])
    np.testing.assert_allclose(g[0, 0, 0], 1 / (1.5e6 * 2j * 0.05) + 1e-9, rtol=1e-14)
    np.testing.assert_allclose(g[1, 1, 1], 1 / 3.0e6 + 1e-9, rtol=1e-14)  # static, Y
    assert g[0, 1, 0] == 0  # the modes are along X and Y only: no coupling


def test_round_trip_file_is_exact(tmp_path):
    model = random_model()
    again = read_modal_model(write_modal_model(model, tmp_path / "m.yaml"))
    assert_same_model(model, again)
    assert again.source == {"method": "oma-h1", "records": ["a", "b"], "fit_error": 0.0312}
    np.testing.assert_array_equal(again.receptance([5.0, 20.0]), model.receptance([5.0, 20.0]))


def test_round_trip_without_optional_parts(tmp_path):
    model = ModalModel([12.0], [0.03], [2e6], [[0.0, 0.0, 3.0]])
    path = write_modal_model(model, tmp_path / "m.yaml")
    text = path.read_text()
    assert "pose" not in text and "residual" not in text and "source" not in text
    assert_same_model(model, read_modal_model(path))


def test_dict_round_trip_and_plain_types():
    model = random_model(seed=3)
    d = modal_model_to_dict(model)
    json.dumps(d)  # plain Python types only (the CLI prints this mapping as JSON)
    yaml.safe_dump(d)
    assert d["format"] == "robomill-modal/1"
    assert_same_model(model, modal_model_from_dict(d))


def test_from_dict_accepts_numpy_values():
    d = {"format": "robomill-modal/1",
         "modes": [{"natural_frequency_hz": np.float64(20.0), "damping_ratio": np.float32(0.05),
                    "stiffness_N_m": np.int64(1_000_000), "direction": np.array([0.0, 1.0, 0.0])}]}
    m = modal_model_from_dict(d)
    assert m.natural_frequency_hz[0] == 20.0 and m.stiffness_N_m[0] == 1e6


def test_from_dict_errors_name_the_given_file():
    with pytest.raises(ModelError, match=r"^identify: modes: expected a list of at least 1, found a list of 0"):
        modal_model_from_dict({"format": "robomill-modal/1", "modes": []}, file="identify")
    with pytest.raises(ModelError, match=r"^<input>: document: expected a robomill-modal/1 mapping"):
        modal_model_from_dict([1, 2])


def test_writer_output_is_plain_safe_yaml(tmp_path):
    path = write_modal_model(random_model(), tmp_path / "m.yaml")
    text = path.read_text()
    assert "!!" not in text and "&" not in text  # no tags, no anchors
    # floats are written with repr: plain yaml.safe_load gets the same doubles back
    assert yaml.safe_load(text)["modes"][0]["direction"] == random_model().directions[0].tolist()


def test_non_unit_direction_is_normalised_with_warning(valid_modal_file):
    edit(valid_modal_file, "direction: [0, 1, 0]", "direction: [0, 3, 4]")
    with pytest.warns(FileWarning, match=r"modes\[1\]\.direction: direction has length 5"):
        m = read_modal_model(valid_modal_file)
    np.testing.assert_allclose(m.directions[1], [0, 0.6, 0.8], rtol=1e-15)


# ------------------------------------------------------------------------------- invalid
@pytest.mark.parametrize("old, new, field, expected, found", [
    ("damping_ratio: 0.05", "damping_ratio: 0", "modes[0].damping_ratio", "a number > 0", "0"),
    ("damping_ratio: 0.04", "damping_ratio: -0.04", "modes[1].damping_ratio", "a number > 0", "-0.04"),
    ("natural_frequency_hz: 10.5", "natural_frequency_hz: 0", "modes[0].natural_frequency_hz", "a number > 0", "0"),
    ("stiffness_N_m: 3.0e6", "stiffness_N_m: -3.0e6", "modes[1].stiffness_N_m", "a number > 0", "-3000000.0"),
    ("stiffness_N_m: 3.0e6", "stiffness_N_m: stiff", "modes[1].stiffness_N_m", "a number > 0", "the text 'stiff'"),
])
def test_bad_mode_values(valid_modal_file, old, new, field, expected, found):
    edit(valid_modal_file, old, new)
    with pytest.raises(ModelError, match=rf"model\.yaml: {re.escape(field)}: expected {expected}, "
                                         rf"found {re.escape(found)}$"):
        read_modal_model(valid_modal_file)


def test_an_overdamped_mode_is_read_with_a_warning_and_keeps_formats_md_receptance(valid_modal_file):
    """A robot's joint damping can make a mode overdamped (``robot model`` writes zeta 1.78 for one):
    the file holds it, G(w) of formats.md holds for it; a warning still catches "5" meant as 5 %."""
    edit(valid_modal_file, "damping_ratio: 0.05", "damping_ratio: 1.78")
    with pytest.warns(FileWarning, match=r"modes\[0\]\.damping_ratio: 1\.78 >= 1, an overdamped mode"):
        m = read_modal_model(valid_modal_file)
    f = np.array([3.0, 10.5, 40.0])
    r = f / m.natural_frequency_hz[0]
    expected = np.outer(m.directions[0], m.directions[0])[:, :, None] / (
        m.stiffness_N_m[0] * (1 - r**2 + 2j * 1.78 * r))
    other = ModalModel(m.natural_frequency_hz[1:], m.damping_ratio[1:], m.stiffness_N_m[1:], m.directions[1:],
                       residual_compliance_m_N=m.residual_compliance_m_N)
    np.testing.assert_allclose(m.receptance(f), expected + other.receptance(f), rtol=1e-12)


def test_residual_compliance_must_be_symmetric_and_a_negative_static_compliance_is_warned(valid_modal_file):
    given = "residual_compliance_m_N: [[1.0e-9, 0, 0], [0, 1.0e-9, 0], [0, 0, 2.0e-9]]"
    text = valid_modal_file.read_text()
    edit(valid_modal_file, given, "residual_compliance_m_N: [[1.0e-9, 2.0e-9, 0], [0, 1.0e-9, 0], [0, 0, 2.0e-9]]")
    with pytest.raises(ModelError, match=r"residual_compliance_m_N: expected a symmetric matrix"):
        read_modal_model(valid_modal_file)
    valid_modal_file.write_text(text.replace(given, "residual_compliance_m_N: [[-1.0e-5, 0, 0], [0, 0, 0], [0, 0, 0]]"))
    with pytest.warns(FileWarning, match="static compliance .* is negative along a direction"):
        read_modal_model(valid_modal_file)


def test_zero_mode_direction(valid_modal_file):
    edit(valid_modal_file, "direction: [1, 0, 0]", "direction: [0, 0, 0]")
    with pytest.raises(ModelError, match=r"model\.yaml: modes\[0\]\.direction: expected a non-zero "
                                         r"direction vector, found a list of 3"):
        read_modal_model(valid_modal_file)


def test_mode_direction_of_two(valid_modal_file):
    edit(valid_modal_file, "direction: [1, 0, 0]", "direction: [1, 0]")
    with pytest.raises(ModelError, match=r"modes\[0\]\.direction: expected a list of 3 numbers, found a list of 2"):
        read_modal_model(valid_modal_file)


def test_residual_compliance_not_3x3(valid_modal_file):
    edit(valid_modal_file, "[[1.0e-9, 0, 0], [0, 1.0e-9, 0], [0, 0, 2.0e-9]]", "[[1.0e-9, 0], [0, 1.0e-9]]")
    with pytest.raises(ModelError, match=r"model\.yaml: residual_compliance_m_N: expected a 3x3 matrix "
                                         r"\(a list of 3 lists of 3 numbers\), found a list of 2"):
        read_modal_model(valid_modal_file)


def test_residual_compliance_with_text_entry(valid_modal_file):
    edit(valid_modal_file, "[0, 0, 2.0e-9]", "[0, zero, 2.0e-9]")
    with pytest.raises(ModelError, match=r"residual_compliance_m_N: expected a 3x3 matrix .* with "
                                         r"finite entries, found the text 'zero' at row 3, column 2"):
        read_modal_model(valid_modal_file)


def test_no_modes(valid_modal_file):
    text = valid_modal_file.read_text()
    start, end = text.index("modes:"), text.index("residual_compliance_m_N")
    valid_modal_file.write_text(text[:start] + "modes: []\n" + text[end:])
    with pytest.raises(ModelError, match=r"modes: expected a list of at least 1, found a list of 0"):
        read_modal_model(valid_modal_file)


def test_mode_not_a_mapping(valid_modal_file):
    edit(valid_modal_file, "  - {natural_frequency_hz: 24.8, damping_ratio: 0.04, stiffness_N_m: 3.0e6, direction: [0, 1, 0]}",
         "  - [24.8, 0.04, 3.0e6]")
    with pytest.raises(ModelError, match=r"modes\[1\]: expected a mode mapping .*found a list of 3"):
        read_modal_model(valid_modal_file)


def test_unknown_key_in_a_mode(valid_modal_file):
    edit(valid_modal_file, "damping_ratio: 0.05,", "damping_ratio: 0.05, mass_kg: 3,")
    with pytest.raises(ModelError, match=r"modes\[0\]\.mass_kg: expected one of the keys natural_frequency_hz, "
                                         r"damping_ratio, stiffness_N_m, direction or an x_ extension"):
        read_modal_model(valid_modal_file)


def test_unknown_key_in_pose(valid_modal_file):
    edit(valid_modal_file, "pose: {joints_deg:", "pose: {robot: kr500, joints_deg:")
    with pytest.raises(ModelError, match=r"pose\.robot: expected one of the keys joints_deg or an x_ extension"):
        read_modal_model(valid_modal_file)


def test_pose_with_five_joints(valid_modal_file):
    edit(valid_modal_file, "59.55, -0.67]}", "59.55]}")
    with pytest.raises(ModelError, match=r"pose\.joints_deg: expected a list of 6 numbers, found a list of 5"):
        read_modal_model(valid_modal_file)


def test_source_is_free_but_must_be_a_mapping(valid_modal_file):
    edit(valid_modal_file, "source: {method: oma-h1,", "source: {anything: [1, 2], method: oma-h1,")
    assert read_modal_model(valid_modal_file).source["anything"] == [1, 2]
    edit(valid_modal_file, "source: {anything: [1, 2], method: oma-h1, records: [rec1], fit_error: 0.03}",
         "source: oma")
    with pytest.raises(ModelError, match=r"model\.yaml: source: expected a mapping \(key: value pairs\), "
                                         r"found the text 'oma'"):
        read_modal_model(valid_modal_file)


@pytest.mark.parametrize("old, new", [
    ("format: robomill-modal/1", "format: robomill-record/1"),
    ("format: robomill-modal/1", "format: 1"),
])
def test_wrong_format(valid_modal_file, old, new):
    edit(valid_modal_file, old, new)
    with pytest.raises(ModelError, match=r"model\.yaml: format: expected 'robomill-modal/1', found"):
        read_modal_model(valid_modal_file)


def test_python_tag(valid_modal_file):
    edit(valid_modal_file, "source: {method: oma-h1, records: [rec1], fit_error: 0.03}",
         "source: !!python/object/new:dict {}")
    with pytest.raises(ModelError, match=r"model\.yaml: line 7: expected plain YAML without "
                                         r"language-specific tags, found the tag .*python/object/new:dict \(not allowed\)"):
        read_modal_model(valid_modal_file)


def test_not_a_mapping(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text("just a sentence\n")
    with pytest.raises(ModelError, match=r"m\.yaml: document: expected a YAML mapping \(key: value lines\), "
                                         r"found the text 'just a sentence'"):
        read_modal_model(path)


def test_missing_file(tmp_path):
    with pytest.raises(ModelError, match=r"absent\.yaml: file: expected an existing file, found no such file"):
        read_modal_model(tmp_path / "absent.yaml")
