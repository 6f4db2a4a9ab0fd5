"""FRF tables: robomill CSV, UFF58 (receptance, mobility, accelerance; ASCII and binary) and the
CutPro-style ``.frf`` text file; the real UFF58 measurement in ../shared/data (formats.md)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import pyuff
from scipy.signal import find_peaks

from oma.errors import FRFError
from oma.frf_io import read_frf, read_uff58_functions, write_frf_csv, write_frf_text, write_frf_uff
from oma.frf_table import FRFTable
from oma.modal import ModalModel
from robot_helpers import SHARED

#: The real impact-test file, kept outside the repository in ../shared/data (data/README.md).
REAL_UFF = SHARED / "data" / "frf-uff58" / "measurement.uff"

#: Peaks of the real file's FRFs, Hz (data/README.md).
REAL_PEAKS_HZ = (142.0, 279.0, 460.0, 687.0, 959.0)
#: The file's resolution is 1 Hz; a peak may sit one line either side of the quoted value.
PEAK_TOLERANCE_HZ = 1.0


def model() -> ModalModel:
    """Two robot-like modes plus an oblique third: every 3x3 entry non-zero."""
    return ModalModel([10.5, 24.8, 41.0], [0.05, 0.04, 0.03], [1.5e6, 3.0e6, 8.0e6],
                      [[1, 0, 0], [0, 1, 0], [0.3, 0.5, 0.8]], residual_compliance_m_N=np.eye(3) * 1e-9)


def table(freq=None, entries=("XX", "YY", "ZZ", "XY", "ZX")) -> FRFTable:
    freq = np.linspace(0.5, 80.0, 318) if freq is None else freq
    return FRFTable.from_model(model(), freq, entries=entries)


def write_uff58(path, freq, values, *, numerator: int, dirs=(1, 1), nodes=(1, 1), binary=0,
                units=None):
    """A UFF file written with pyuff directly (independent of robomill's writer)."""
    sets = []
    if units is not None:
        sets.append(pyuff.prepare_164(units_code=9, units_description="user", temp_mode=1,
                                      length=units[0], force=units[1], temp=1.0, temp_offset=0.0))
    for vals, (rd, fd), (rn, fn) in zip(values, dirs if isinstance(dirs[0], tuple) else [dirs],
                                        nodes if isinstance(nodes[0], tuple) else [nodes]):
        sets.append(pyuff.prepare_58(
            binary=binary, func_type=4, rsp_node=rn, rsp_dir=rd, ref_node=fn, ref_dir=fd,
            data=np.asarray(vals, dtype=complex), x=np.asarray(freq, dtype=float), id1="test",
            abscissa_spacing=1, abscissa_spec_data_type=18, ordinate_spec_data_type=numerator,
            orddenom_spec_data_type=13))
    path.write_text("")  # then "add": pyuff 2.5's binary "overwrite" truncates a first dataset 58
    pyuff.UFF(str(path)).write_sets(sets, mode="add")
    return path


# ----------------------------------------------------------------------------------------- CSV
def test_csv_fixture_reads_the_model_it_was_sampled_from(valid_frf_csv):
    t = read_frf(valid_frf_csv)
    assert t.entry_names == ["XX", "XY", "YY"]
    assert t.measured.sum() == 3 and t.meta["format"] == "csv"
    m = ModalModel([10.5, 24.8], [0.05, 0.04], [1.5e6, 3.0e6], [[1, 0, 0], [0.6, 0.8, 0]])
    np.testing.assert_array_equal(t.entry("XX"), m.receptance(t.freq_hz)[0, 0])
    np.testing.assert_array_equal(t.entry("XY"), m.receptance(t.freq_hz)[0, 1])
    np.testing.assert_array_equal(t.entry("YY"), m.receptance(t.freq_hz)[1, 1])
    assert not t.measured[1, 0]  # YX was not in the file


def test_csv_round_trip_is_exact(tmp_path):
    t = table()
    back = read_frf(write_frf_csv(t, tmp_path / "frf.csv"))
    np.testing.assert_array_equal(back.freq_hz, t.freq_hz)
    np.testing.assert_array_equal(back.receptance_m_N, t.receptance_m_N)
    np.testing.assert_array_equal(back.measured, t.measured)
    header = (tmp_path / "frf.csv").read_text().splitlines()[0]
    assert header == "freq_hz,XX_re,XX_im,XY_re,XY_im,YY_re,YY_im,ZX_re,ZX_im,ZZ_re,ZZ_im"


@pytest.mark.parametrize("header, field, expected, found", [
    ("frequency,XX_re,XX_im", "header column 1", "freq_hz", "'frequency'"),
    ("freq_hz,XX_re,XX_im,XW_re", "column XW_re", "freq_hz then pairs", "the column 'XW_re'"),
    ("freq_hz,XX_re,XX_im,XX_abs", "column XX_abs", "freq_hz then pairs", "the column 'XX_abs'"),
])
def test_csv_bad_header(tmp_path, header, field, expected, found):
    ncol = header.count(",") + 1
    path = tmp_path / "bad.csv"
    path.write_text(header + "\n" + ",".join(["1.0"] * ncol) + "\n")
    with pytest.raises(FRFError, match=rf"bad\.csv: {re.escape(field)}: expected {re.escape(expected)}.*, "
                                       rf"found {re.escape(found)}"):
        read_frf(path)


def test_csv_entry_without_imaginary_part(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("freq_hz,XX_re,XX_im,YY_re\n1.0,1e-7,0,1e-7\n")
    with pytest.raises(FRFError, match=r"bad\.csv: column YY_im: expected both YY_re and YY_im, found no YY_im column"):
        read_frf(path)


def test_csv_frequencies_not_increasing(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("freq_hz,XX_re,XX_im\n1.0,1e-7,0\n2.0,1e-7,0\n2.0,1e-7,0\n")
    with pytest.raises(FRFError, match=r"bad\.csv: column freq_hz, row 3: expected increasing frequencies, found 2\.0 after 2\.0"):
        read_frf(path)


def test_csv_negative_frequency(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("freq_hz,XX_re,XX_im\n-1.0,1e-7,0\n2.0,1e-7,0\n")
    with pytest.raises(FRFError, match=r"column freq_hz, row 1: expected finite frequencies >= 0 Hz, found -1\.0"):
        read_frf(path)


def test_csv_nan_value(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("freq_hz,XX_re,XX_im\n1.0,1e-7,0\n2.0,nan,0\n")
    with pytest.raises(FRFError, match=r"bad\.csv: column XX_re, row 2: expected finite numbers, found nan"):
        read_frf(path)


def test_csv_ragged_row(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("freq_hz,XX_re,XX_im\n1.0,1e-7,0\n2.0,1e-7\n")
    with pytest.raises(FRFError, match=r"bad\.csv: line 3: expected 3 values \(one per header column\), found 2 values"):
        read_frf(path)


def test_csv_without_rows(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("freq_hz,XX_re,XX_im\n")
    with pytest.raises(FRFError, match=r"bad\.csv: column freq_hz: expected at least two frequency lines .*, "
                                       r"found no rows"):
        read_frf(path)
    # one line is a value, not a response (the lobes from it found no chatter anywhere: limit inf)
    path.write_text("freq_hz,XX_re,XX_im\n2.0,1e-7,-1e-8\n")
    with pytest.raises(FRFError, match=r"bad\.csv: column freq_hz: expected at least two frequency lines .*, "
                                       r"found one line"):
        read_frf(path)


def test_missing_file_and_unknown_suffix(tmp_path):
    with pytest.raises(FRFError, match=r"none\.csv: file: expected an existing file, found no such file"):
        read_frf(tmp_path / "none.csv")
    with pytest.raises(FRFError, match=r"frf\.txt: file: expected an FRF file ending in \.csv, \.uff, "
                                       r"\.unv or \.frf, found the suffix '\.txt'"):
        read_frf(tmp_path / "frf.txt")


def test_axis_is_only_for_frf_files(valid_frf_csv):
    with pytest.raises(FRFError, match=r"frf\.csv: axis: expected no axis for a \.csv file"):
        read_frf(valid_frf_csv, axis="X")


# ---------------------------------------------------------------------------------------- .frf
def test_cutpro_text_read_with_axis(tmp_path):
    g = model().receptance([5.0, 10.0, 15.0])[1, 1]
    path = tmp_path / "tip.frf"
    path.write_text("Frequency(Hz)   Real(m/N)   Imag(m/N)\n"
                    + "".join(f"  {f!r}\t{float(z.real)!r}   {float(z.imag)!r}\n"
                            for f, z in zip([5.0, 10.0, 15.0], g)))
    t = read_frf(path, axis="Y")
    assert t.entry_names == ["YY"] and t.meta["format"] == "frf"
    np.testing.assert_array_equal(t.entry("YY"), g)


def test_cutpro_text_round_trip(tmp_path):
    t = table(entries=("XX", "ZZ"))
    back = read_frf(write_frf_text(t, tmp_path / "z.frf", axis="Z"), axis="z")
    np.testing.assert_array_equal(back.entry("ZZ"), t.entry("ZZ"))
    np.testing.assert_array_equal(back.freq_hz, t.freq_hz)


@pytest.mark.parametrize("axis", [None, "W", 1])
def test_cutpro_text_needs_an_axis(tmp_path, axis):
    path = write_frf_text(table(entries=("XX",)), tmp_path / "x.frf", axis="X")
    with pytest.raises(FRFError, match=r"x\.frf: axis: expected the axis X, Y or Z of this direct FRF"):
        read_frf(path, axis=axis)


def test_cutpro_text_bad_line(tmp_path):
    path = tmp_path / "bad.frf"
    path.write_text("f re im\n1.0 2e-7 -1e-8\n2.0 2e-7\n")
    with pytest.raises(FRFError, match=r"bad\.frf: line 3: expected three numbers: frequency \(Hz\), "
                                       r"real, imaginary \(m/N\), found 2 numbers"):
        read_frf(path, axis="X")
    path.write_text("f re im\n1.0 2e-7 -1e-8\n2.0 2e-7 oops\n")
    with pytest.raises(FRFError, match=r"bad\.frf: line 3: expected three numbers.*found the text '2\.0 2e-7 oops'"):
        read_frf(path, axis="X")


# ---------------------------------------------------------------------------------------- UFF58
def test_uff_binary_round_trip_is_exact(tmp_path):
    t = table()
    back = read_frf(write_frf_uff(t, tmp_path / "t.uff"))
    np.testing.assert_array_equal(back.freq_hz, t.freq_hz)
    np.testing.assert_array_equal(back.receptance_m_N, t.receptance_m_N)
    np.testing.assert_array_equal(back.measured, t.measured)
    assert back.meta["kinds"] == {e: "receptance" for e in t.entry_names} and back.meta["node"] == 1


def test_uff_ascii_round_trip_to_the_format_precision(tmp_path):
    t = table()
    back = read_frf(write_frf_uff(t, tmp_path / "t.unv", binary=False))
    # ASCII dataset 58 writes frequencies as E13.5 (6 significant digits), values as E20.11
    np.testing.assert_allclose(back.freq_hz, t.freq_hz, rtol=5e-6, atol=0)
    scale = np.abs(t.receptance_m_N).max()
    np.testing.assert_allclose(back.receptance_m_N, t.receptance_m_N, rtol=5e-11, atol=5e-12 * scale)


@pytest.mark.parametrize("kind, numerator, factor", [
    ("mobility", 11, lambda w: 1j * w),
    ("accelerance", 12, lambda w: -(w**2)),
])
def test_uff_mobility_and_accelerance_become_receptance(tmp_path, kind, numerator, factor):
    freq = np.arange(0.0, 80.25, 0.25)  # starts at 0 Hz, where only the receptance is undefined
    g = model().receptance(freq)[2, 0]
    w = 2 * np.pi * freq
    path = write_uff58(tmp_path / f"{kind}.uff", freq, [factor(w) * g], numerator=numerator,
                       dirs=(3, 1), binary=1)
    t = read_frf(path)
    assert t.entry_names == ["ZX"] and t.meta["kinds"] == {"ZX": kind}
    np.testing.assert_array_equal(t.freq_hz, freq[1:])  # the 0 Hz line is left out
    np.testing.assert_allclose(t.entry("ZX"), g[1:], rtol=1e-13)  # 2-3 roundings of 1e-16


def test_uff_units_dataset_is_applied(tmp_path):
    # mm and N: UFF 164 factors are file units per SI unit (1000 mm per m), SI = value * F / L
    freq = np.arange(1.0, 40.0)
    g = model().receptance(freq)[0, 0]
    path = write_uff58(tmp_path / "mm.uff", freq, [g * 1e3], numerator=8, units=(1000.0, 1.0), binary=1)
    np.testing.assert_allclose(read_frf(path).entry("XX"), g, rtol=1e-15)


def test_uff_negative_direction_flips_sign(tmp_path):
    freq = np.arange(1.0, 40.0)
    g = model().receptance(freq)[1, 0]
    path = write_uff58(tmp_path / "neg.uff", freq, [-g], numerator=8, dirs=(-2, 1), binary=1)
    np.testing.assert_array_equal(read_frf(path).entry("YX"), g)


def test_uff_several_nodes_need_node(tmp_path):
    freq = np.arange(1.0, 40.0)
    g = model().receptance(freq)
    path = write_uff58(tmp_path / "rove.uff", freq, [g[0, 0], g[0, 0] * 0.5], numerator=8,
                       dirs=((1, 1), (1, 1)), nodes=((1, 1), (7, 7)), binary=1)
    with pytest.raises(FRFError, match=r"rove\.uff: nodes: expected FRFs at one tool-tip node .*"
                                       r"found response/reference nodes 1/1, 7/7"):
        read_frf(path)
    np.testing.assert_array_equal(read_frf(path, node=7).entry("XX"), g[0, 0] * 0.5)
    with pytest.raises(FRFError, match=r"rove\.uff: node: expected a node with FRFs measured at it .*found node 3"):
        read_frf(path, node=3)


def test_uff_garbage_file(tmp_path):
    path = tmp_path / "junk.uff"
    path.write_bytes(b"\x00\x01 this is not a universal file \xff" * 20)
    with pytest.raises(FRFError, match=r"junk\.uff: "):
        read_frf(path)


def test_uff_without_frf(tmp_path):
    path = tmp_path / "units_only.uff"
    pyuff.UFF(str(path)).write_sets([pyuff.prepare_164(units_code=1, units_description="SI", temp_mode=1,
                                                       length=1.0, force=1.0, temp=1.0, temp_offset=273.15)],
                                    mode="overwrite")
    with pytest.raises(FRFError, match=r"units_only\.uff: datasets: expected at least one FRF \(dataset 58, "
                                       r"function type 4\), found dataset types \[164\]"):
        read_frf(path)


# ---------------------------------------------------------------------------- real measurement
@pytest.mark.skipif(not REAL_UFF.exists(), reason=f"real UFF58 data not present at {REAL_UFF}")
def test_real_uff58_measurement_peaks_and_conversion():
    functions = read_uff58_functions(REAL_UFF)
    assert [(f.response_node, f.response_direction, f.reference_node, f.reference_direction)
            for f in functions] == [(1, 1, 1, 1), (1, 1, 2, 1), (1, 1, 3, 1)]
    assert {f.kind for f in functions} == {"accelerance"}
    raw = pyuff.UFF(str(REAL_UFF)).read_sets()  # read independently of robomill
    for f, r in zip(functions, raw):
        assert r["x"][0] == 0.0 and r["x"][-1] == 1000.0 and r["x"].size == 1001
        np.testing.assert_array_equal(f.freq_hz, r["x"][1:])  # 1..1000 Hz: 0 Hz left out
        # accelerance = -(2 pi f)^2 * receptance, against the file's own numbers (no units dataset)
        w = 2 * np.pi * f.freq_hz
        np.testing.assert_allclose(-(w**2) * f.receptance_m_N, r["data"][1:], rtol=1e-14)
        np.testing.assert_array_equal(f.measured, r["data"][1:])
    # The driving-point FRF shows all five peaks; each transfer FRF's peaks are among them.
    # (Ref. node 3 shows no 142 Hz peak and node 2 barely a 460 Hz one: nodal points of those modes.)
    for i, f in enumerate(functions):
        a = np.abs(f.measured)
        peaks, _ = find_peaks(a, prominence=0.15 * a.max())
        found = f.freq_hz[peaks]
        main = found[found > 100]  # the file also has a small 52 Hz bump
        for p in main:
            assert min(abs(p - q) for q in REAL_PEAKS_HZ) <= PEAK_TOLERANCE_HZ, (i, p)
        if i == 0:
            assert len(main) == 5
    # As a table: node 1 is the one measured at itself (the driving point), direction 1 -> X
    t = read_frf(REAL_UFF, node=1)
    assert t.entry_names == ["XX"]
    np.testing.assert_array_equal(t.entry("XX"), functions[0].receptance_m_N)
    # without node=: the driving point is the only node measured at itself, so it is the tool tip
    # (the CLI has no node option: this file was unusable from it), the transfer FRFs left out, said
    with pytest.warns(UserWarning, match=r"FRFs between other nodes \(1/2, 1/3\) left out: node 1"):
        auto = read_frf(REAL_UFF)
    np.testing.assert_array_equal(auto.entry("XX"), t.entry("XX"))
