"""Adapter for the measured CNC cuts of ``milling-vibration-hurco`` and their chatter table.

The files (``../shared/data/milling-vibration-hurco/EBI_*.csv``, see the data README) hold
triaxial accelerations of a Hurco VMX42SRTi during milling, about 1650 Hz, with columns ``Time
(s), Accel X (m/s^2), Accel Y (m/s^2), Accel Z (m/s^2), CI Value``. What is known comes from the
file names and the README: the spindle speed (``4000RPM``, ``7000RPMto6000RPM``), 4 flutes in
4140 steel at 4000 rpm, 3 flutes in aluminium otherwise, ``T25..T100`` the radial engagement in %
of the diameter, the axial depth in inches (``0p125IN``, ``D0p05IN``) and the feed in in/min
(``F20IN``). ``CI Value`` is the source project's own chatter indicator: the product over X and Y of
the standard deviation of once-per-revolution samples of the (integrated) displacement over its
overall standard deviation, per 0.3 s window; its detector calls chatter above 0.9. It is not a
ground truth (and the source's script computed it with a fixed sampling rate and spindle speed).

:func:`analyse_hurco_file` runs :func:`~planner.diagnosis.chatter.detect_chatter` on consecutive
windows of the part of the record where the tool cuts (blocks whose RMS acceleration exceeds a
quarter of the 90th percentile of all blocks; the idle tail of a record is left out), with the
spindle frequency refined around each nominal speed of the name (the one whose harmonic comb
carries more energy wins). Nothing here is tuned to these files.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from oma._arrays import readonly as _ro
from oma.errors import InputError

from .chatter import ChatterResult, comb_energy, detect_chatter
from .spectral import fold_frequency

__all__ = ["HurcoRecording", "HurcoWindow", "HurcoRow", "read_hurco_csv", "analyse_hurco_file", "hurco_table",
           "DEFAULT_DIRECTORY", "CI_THRESHOLD"]

#: Where the data live relative to the repository (the data README's ``../shared/data``).
DEFAULT_DIRECTORY = Path(__file__).resolve().parents[3] / "shared" / "data" / "milling-vibration-hurco"
#: The source project's chatter threshold on its indicator.
CI_THRESHOLD = 0.9
HEADER = ("Time (s)", "Accel X (m/s^2)", "Accel Y (m/s^2)", "Accel Z (m/s^2)", "CI Value")


@dataclass(frozen=True)
class HurcoRecording:
    """One Hurco file, SI, with what its name says.

    Attributes
    ----------
    name : str
    time_s : ndarray, shape (n,)
    acceleration_m_s2 : ndarray, shape (3, n)
    ci : ndarray, shape (n,)
        The source's chatter indicator.
    sample_rate_hz : float
        From the median time step.
    spindle_rpm : tuple of float
        Nominal speeds in the name (two when it changed during the cut).
    teeth : int
    material : str
    radial_engagement_percent, axial_depth_in, feed_in_min : float or None
    """

    name: str
    time_s: np.ndarray = field(repr=False)
    acceleration_m_s2: np.ndarray = field(repr=False)
    ci: np.ndarray = field(repr=False)
    sample_rate_hz: float
    spindle_rpm: tuple
    teeth: int
    material: str
    radial_engagement_percent: float | None = None
    axial_depth_in: float | None = None
    feed_in_min: float | None = None

    def __post_init__(self):
        for name in ("time_s", "acceleration_m_s2", "ci"):
            object.__setattr__(self, name, _ro(getattr(self, name)))


def _inches(token: str) -> float:
    return float(token.replace("p", "."))


def read_hurco_csv(path) -> HurcoRecording:
    """Read one ``EBI_*.csv`` file.

    Raises
    ------
    InputError
        A header other than the five expected columns, a name without ``RPM``, or a time column
        that does not increase.
    """
    path = Path(path)
    with open(path, encoding="utf-8") as fh:
        header = tuple(h.strip() for h in fh.readline().strip().split(","))
    if header != HEADER:
        raise InputError(path, "header", ", ".join(HEADER), ", ".join(header))
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.shape[1] != 5 or data.shape[0] < 16:
        raise InputError(path, "rows", "at least 16 rows of 5 numbers", f"{data.shape[0]} rows of {data.shape[1]}")
    t = data[:, 0]
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise InputError(path, "column Time (s)", "increasing times", "a step <= 0")
    stem = path.stem
    rpms = tuple(float(v) for v in re.findall(r"(\d+)RPM", stem))
    if not rpms:
        raise InputError(path, "file name", "a spindle speed like 4000RPM", stem)
    steel = any(abs(r - 4000.0) < 1 for r in rpms)
    radial = re.search(r"_T(\d+)_", stem)
    depth = re.search(r"_D?(\d+p\d+)IN", stem)
    feed = re.search(r"_F(\d+)IN", stem)
    return HurcoRecording(
        name=path.name, time_s=t, acceleration_m_s2=data[:, 1:4].T, ci=data[:, 4],
        sample_rate_hz=float(1.0 / np.median(dt)), spindle_rpm=rpms, teeth=4 if steel else 3,
        material="4140 steel" if steel else "aluminium",
        radial_engagement_percent=float(radial.group(1)) if radial else None,
        axial_depth_in=_inches(depth.group(1)) if depth else None,
        feed_in_min=float(feed.group(1)) if feed else None)


def cutting_span(x, sample_rate_hz: float, *, block_s: float = 0.5, fraction: float = 0.25) -> slice:
    """Samples from the first to the last block whose RMS exceeds ``fraction`` of the 90th
    percentile of the block RMS values (the tool is in the cut)."""
    x = np.asarray(x, dtype=float)
    nb = max(int(round(block_s * sample_rate_hz)), 1)
    n_blocks = x.shape[-1] // nb
    rms = np.array([np.std(x[:, i * nb:(i + 1) * nb]) for i in range(n_blocks)])
    on = rms >= fraction * np.percentile(rms, 90)
    first = int(np.argmax(on))
    last = n_blocks - int(np.argmax(on[::-1]))
    return slice(first * nb, last * nb)


@dataclass(frozen=True)
class HurcoWindow:
    """Detection in one window: start time (s, from the file's first sample), nominal rpm used."""

    start_s: float
    spindle_rpm: float
    result: ChatterResult


@dataclass(frozen=True)
class HurcoRow:
    """One file of the chatter table.

    Attributes
    ----------
    file, material : str
    teeth : int
    spindle_rpm : tuple of float
        Nominal speeds from the name.
    sample_rate_hz : float
    tooth_hz_nominal : tuple of float
        ``rpm * teeth / 60`` folded into ``[0, fs/2]``, per nominal speed.
    tooth_hz : float
        Tooth-passing frequency found (median over windows; folded).
    chatter : bool
        At least half of the cutting windows show chatter.
    chatter_hz : float
        Median frequency of the chatter windows (as seen in the sampled signal; NaN if none).
    chatter_kind : str
    windows_with_chatter, n_windows : int
    ci_median : float
        Median of the source's indicator over the analysed span.
    ci_chatter : bool
        ``ci_median > CI_THRESHOLD``.
    windows : tuple of HurcoWindow
    """

    file: str
    material: str
    teeth: int
    spindle_rpm: tuple
    sample_rate_hz: float
    tooth_hz_nominal: tuple
    tooth_hz: float
    chatter: bool
    chatter_hz: float
    chatter_kind: str
    windows_with_chatter: int
    n_windows: int
    ci_median: float
    ci_chatter: bool
    windows: tuple = field(repr=False, default=())

    @property
    def agrees_with_ci(self) -> bool:
        return bool(self.chatter == self.ci_chatter)

    def to_dict(self) -> dict:
        def num(x):
            return round(float(x), 3) if math.isfinite(float(x)) else None

        return {"file": self.file, "material": self.material, "teeth": self.teeth,
                "spindle_rpm": list(self.spindle_rpm), "sample_rate_hz": round(self.sample_rate_hz, 2),
                "tooth_hz_nominal": [num(f) for f in self.tooth_hz_nominal], "tooth_hz": num(self.tooth_hz),
                "chatter": bool(self.chatter), "chatter_hz": num(self.chatter_hz), "chatter_kind": self.chatter_kind,
                "windows_with_chatter": int(self.windows_with_chatter), "n_windows": int(self.n_windows),
                "ci_median": num(self.ci_median), "ci_chatter": bool(self.ci_chatter),
                "agrees_with_ci": self.agrees_with_ci,
                "window_tooth_hz": [num(w.result.tooth_hz) for w in self.windows]}


def analyse_hurco_file(path, *, window_s: float = 2.0, **detect_kwargs) -> HurcoRow:
    """Chatter detection on the cutting windows of one file (module notes).

    Parameters
    ----------
    path : path-like
    window_s : float
        Window length, s.
    **detect_kwargs
        Passed to :func:`~planner.diagnosis.chatter.detect_chatter`.
    """
    rec = read_hurco_csv(path)
    fs = rec.sample_rate_hz
    x = rec.acceleration_m_s2
    span = cutting_span(x, fs)
    nw = max(int(round(window_s * fs)), 64)
    starts = list(range(span.start, max(span.stop - nw, span.start) + 1, nw))
    windows = []
    for i0 in starts:
        seg = x[:, i0:min(i0 + nw, span.stop)]
        best = None
        for rpm in rec.spindle_rpm:
            res = detect_chatter(seg, fs, rpm / 60.0, rec.teeth, **detect_kwargs)
            energy = 0.0
            if len(rec.spindle_rpm) > 1:
                xw = seg - seg.mean(axis=1, keepdims=True)
                xw = xw * np.hanning(xw.shape[1])[None, :]
                energy = comb_energy(xw, fs, res.spindle_hz, max(int(0.5 * fs / res.spindle_hz), 1))
            if best is None or energy > best[0]:
                best = (energy, rpm, res)
        windows.append(HurcoWindow(start_s=float(rec.time_s[i0] - rec.time_s[0]), spindle_rpm=best[1],
                                   result=best[2]))
    flags = [w.result.chatter for w in windows]
    n_chat = int(sum(flags))
    chat_freqs = [w.result.frequency_hz for w in windows if w.result.chatter]
    kinds = [w.result.kind for w in windows if w.result.chatter]
    ci = float(np.median(rec.ci[span]))
    return HurcoRow(
        file=rec.name, material=rec.material, teeth=rec.teeth, spindle_rpm=rec.spindle_rpm, sample_rate_hz=fs,
        tooth_hz_nominal=tuple(float(fold_frequency(r * rec.teeth / 60.0, fs)) for r in rec.spindle_rpm),
        tooth_hz=float(np.median([w.result.tooth_hz for w in windows])),
        chatter=bool(2 * n_chat >= len(windows) and n_chat > 0),
        chatter_hz=float(np.median(chat_freqs)) if chat_freqs else float("nan"),
        chatter_kind=max(set(kinds), key=kinds.count) if kinds else "none",
        windows_with_chatter=n_chat, n_windows=len(windows), ci_median=ci, ci_chatter=ci > CI_THRESHOLD,
        windows=tuple(windows))


def hurco_table(directory=None, **kwargs) -> list[dict]:
    """Rows (one per file, sorted by name) of :func:`analyse_hurco_file`, as dictionaries.

    Raises
    ------
    FileNotFoundError
        When the directory holds no ``EBI_*.csv`` file.
    """
    directory = DEFAULT_DIRECTORY if directory is None else Path(directory)
    files = sorted(Path(directory).glob("EBI_*.csv"))
    if not files:
        raise FileNotFoundError(f"no EBI_*.csv file in {directory}")
    return [analyse_hurco_file(f, **kwargs).to_dict() for f in files]
