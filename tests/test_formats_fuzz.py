"""Damaged records never crash the reader: ``read_record`` returns a Record or raises an
InputError subclass (formats.md: a bad file is reported as file/field/expected/found, never as a
traceback). Hypothesis damages a valid record directory in the ways real files get damaged:
YAML keys dropped, added or given values of random types, YAML text truncated or spliced with
garbage, CSV lines truncated, corrupted, duplicated or shuffled, NaN inserted, files emptied or
replaced by binary garbage, the npz archive's bytes damaged."""

from __future__ import annotations

import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from oma.errors import InputError
from oma.record import Record
from oma.record_io import read_record

# Values of every YAML type, nested a little: what a careless edit or a buggy exporter writes.
scalars = (st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=True)
           | st.text(max_size=12) | st.sampled_from(["X", "um", "g", "time", "down", "1.0e-3", ""]))
values = st.recursive(scalars, lambda kids: st.lists(kids, max_size=4)
                      | st.dictionaries(st.text(max_size=6), kids, max_size=3), max_leaves=6)
keys = st.text(min_size=1, max_size=12) | st.sampled_from(
    ["format", "name", "tool", "cut", "signals", "columns", "unit", "axis", "quantity", "file", "x_note",
     "teeth", "window_s", "sample_rate_hz", "joints_deg", "robot"])


def _paths(node, prefix=()):
    """Every path (tuple of keys / indices) into nested dicts and lists."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


def _parent(doc, path):
    node = doc
    for k in path[:-1]:
        node = node[k]
    return node


def _numbers(node):
    """Undo PyYAML's YAML 1.1 reading of ``1.2e8`` as text, so a re-dumped file stays valid."""
    if isinstance(node, dict):
        return {k: _numbers(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_numbers(v) for v in node]
    if isinstance(node, str):
        try:
            return float(node)
        except ValueError:
            return node
    return node


def mutate_yaml(data, text: str) -> str:
    doc = _numbers(yaml.safe_load(text))
    paths = [p for p in _paths(doc) if p]
    kind = data.draw(st.sampled_from(["drop", "insert", "replace", "replace", "truncate", "splice"]),
                     label="yaml mutation")
    if kind in ("drop", "insert", "replace"):
        path = data.draw(st.sampled_from(paths), label="path")
        parent = _parent(doc, path)
        if kind == "drop":
            del parent[path[-1]]
        elif kind == "insert":
            target = parent[path[-1]] if isinstance(parent[path[-1]], dict) else parent
            if isinstance(target, dict):
                target[data.draw(keys, label="new key")] = data.draw(values, label="new value")
            else:
                target.insert(0, data.draw(values, label="new item"))
        else:
            parent[path[-1]] = data.draw(values, label="value")
        return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)
    if kind == "truncate":
        return text[: data.draw(st.integers(0, len(text)), label="cut at")]
    at = data.draw(st.integers(0, len(text)), label="splice at")
    junk = data.draw(st.text(max_size=20) | st.sampled_from(
        ["!!python/object/apply:os.system ['true']", ": :", "\t", "- [", "&a *a", "{", "%YAML 9.9"]),
        label="junk")
    return text[:at] + junk + text[at:]


def mutate_csv(data, text: str) -> str:
    lines = text.splitlines()
    kind = data.draw(st.sampled_from(["truncate_line", "corrupt", "nan", "shuffle", "drop_rows",
                                      "duplicate", "extra_cell", "header"]), label="csv mutation")
    i = data.draw(st.integers(1, len(lines) - 1), label="line")
    if kind == "truncate_line":
        lines[i] = lines[i][: data.draw(st.integers(0, len(lines[i])), label="cut at")]
    elif kind == "corrupt":
        at = data.draw(st.integers(0, len(lines[i])), label="at")
        lines[i] = lines[i][:at] + data.draw(st.text(max_size=4), label="chars") + lines[i][at + 1:]
    elif kind == "nan":
        cells = lines[i].split(",")
        cells[data.draw(st.integers(0, len(cells) - 1), label="cell")] = data.draw(
            st.sampled_from(["nan", "inf", "-inf", "NaN", "1e999", ""]), label="value")
        lines[i] = ",".join(cells)
    elif kind == "shuffle":
        body = lines[1:]
        perm = data.draw(st.permutations(range(min(len(body), 6))), label="perm")
        body[: len(perm)] = [body[p] for p in perm]
        lines = lines[:1] + body
    elif kind == "drop_rows":
        lines = lines[: i]
    elif kind == "duplicate":
        lines.insert(i, lines[i])
    elif kind == "extra_cell":
        lines[i] += "," + data.draw(st.sampled_from(["0", "x", ""]), label="cell")
    else:
        lines[0] = data.draw(st.sampled_from(["", "t,Fx", "t,Fx,Fy,Fz,x,y,z,w", "t,Fx,Fx,Fz,x,y,z",
                                              "T,Fx,Fy,Fz,x,y,z"]), label="header")
    return "\n".join(lines) + "\n"


def damage(data, directory: Path) -> None:
    target = data.draw(st.sampled_from(["yaml", "yaml", "signals", "signals", "empty", "garbage"]),
                       label="target")
    yaml_path = directory / "record.yaml"
    signals = next(p for p in directory.iterdir() if p.name.startswith("signals"))
    if target == "yaml":
        yaml_path.write_text(mutate_yaml(data, yaml_path.read_text()), encoding="utf-8")
    elif target == "signals" and signals.suffix == ".csv":
        signals.write_text(mutate_csv(data, signals.read_text()))
    elif target == "signals":
        raw = bytearray(signals.read_bytes())
        at = data.draw(st.integers(0, len(raw) - 1), label="byte")
        if data.draw(st.booleans(), label="truncate"):
            del raw[at:]
        else:
            raw[at: at + 8] = data.draw(st.binary(min_size=1, max_size=8), label="bytes")
        signals.write_bytes(bytes(raw))
    else:
        victim = data.draw(st.sampled_from([yaml_path, signals]), label="file")
        victim.write_bytes(b"" if target == "empty" else data.draw(st.binary(max_size=200), label="garbage"))


def _check_damaged(base: Path, data) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp) / "rec"
        shutil.copytree(base, directory)
        damage(data, directory)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a normalised direction warns; that is not a failure
            try:
                result = read_record(directory)
            except InputError as exc:  # the only acceptable failure, with a one-line message
                assert str(exc) and "\n" not in str(exc)
                assert exc.file is not None
                return
        assert isinstance(result, Record)
        assert np.all(np.isfinite(result.data)) and result.n_samples >= 1


# The fixtures write a fresh valid record per test function; every example copies it before
# damaging it, so sharing the function-scoped fixture across examples is safe.
FUZZ = settings(max_examples=120, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@FUZZ
@given(data=st.data())
def test_damaged_csv_record_reads_or_raises_input_error(valid_record_dir, data):
    _check_damaged(valid_record_dir, data)


@settings(FUZZ, max_examples=80)
@given(data=st.data())
def test_damaged_npz_record_reads_or_raises_input_error(valid_record_npz_dir, data):
    _check_damaged(valid_record_npz_dir, data)
