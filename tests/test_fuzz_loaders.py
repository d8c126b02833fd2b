"""Property-based tests of the loaders (hypothesis): whatever the bytes, a loader returns a
valid object or raises its one documented error class with a one-line message; nothing
else escapes (no KeyError, ZeroDivisionError, RecursionError...), and what loads can be
used by the analysis without a crash.

CI runs a bounded, derandomized number of examples; BLADESONAR_FUZZ_EXAMPLES=5000 runs
more (and random ones), e.g. before a release.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import struct
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bladesonar import cli, config
from bladesonar.analyzer import new_analyzer
from bladesonar.errors import BladesonarError, ConfigError, InputError, ReferenceFileError
from bladesonar.io.reference import checksum, parse_reference, reference_bytes
from bladesonar.io.safe_yaml import parse_yaml
from bladesonar.io.scene_file import load_scene
from bladesonar.io.wav import read_wav
from bladesonar.reference_build import build_reference
from bladesonar.sim.render import simulate
from bladesonar.sim.scene import Scene
from bladesonar.sim.schedule import Schedule
from loopback import SCENE

_N = os.environ.get("BLADESONAR_FUZZ_EXAMPLES")
FUZZ = settings(max_examples=int(_N) if _N else 50, deadline=None, database=None,
                derandomize=not _N,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
#: Longest message a loader may give, characters.
MAX_MESSAGE = 800


def one_line(exc: Exception) -> None:
    msg = str(exc)
    assert "\n" not in msg and 0 < len(msg) <= MAX_MESSAGE, msg[:2000]


class _Good(tuple):
    """(reference, its file bytes), with a short repr for hypothesis' reports."""

    def __repr__(self) -> str:
        return "<good reference>"


@pytest.fixture(scope="module")
def good_ref():
    cfg = config.Config()
    x, _ = simulate(load_scene(SCENE), cfg, 8.0, schedule=Schedule.constant(0.45, "ccw"),
                    snr_db=20.0, seed=5)
    ref = build_reference(x, cfg, "ccw")
    return _Good((ref, reference_bytes(ref)))


def _npz(table, mean_pulse, meta) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, table=table, mean_pulse=mean_pulse, meta=np.array(json.dumps(meta)))
    return buf.getvalue()


def _check_loaded(ref) -> None:
    """What a loaded reference promises: shapes, finite values, a usable analyzer."""
    B, L = ref.table.shape
    assert ref.mean_pulse.shape == (L,) and B == ref.meta["phase_bins"]
    assert np.all(np.isfinite(ref.table)) and np.all(np.isfinite(ref.mean_pulse))
    assert 0 < ref.cycles_per_pulse <= 0.5 and ref.meta["rate_hz"] > 0
    nested: dict = {}
    for key, value in ref.meta["depends"].items():
        sec, name = key.split(".", 1)
        nested.setdefault(sec, {})[name] = value
    cfg = config.from_mapping(nested)
    try:
        new_analyzer(cfg, ref)
    except BladesonarError:
        pass


# -- references --------------------------------------------------------------------------

@FUZZ
@given(data=st.data())
def test_damaged_reference_bytes_load_or_give_one_error(good_ref, data):
    _, good = good_ref
    b = bytearray(good)
    how = data.draw(st.sampled_from(["flip", "truncate", "insert", "overwrite"]))
    if how == "flip":
        for pos, bit in data.draw(st.lists(st.tuples(st.integers(0, len(b) - 1),
                                                     st.integers(0, 7)), min_size=1,
                                           max_size=8)):
            b[pos] ^= 1 << bit
    elif how == "truncate":
        b = b[:data.draw(st.integers(0, len(b) - 1))]
    elif how == "insert":
        pos = data.draw(st.integers(0, len(b)))
        b[pos:pos] = data.draw(st.binary(min_size=1, max_size=64))
    else:
        pos = data.draw(st.integers(0, len(b) - 1))
        chunk = data.draw(st.binary(min_size=1, max_size=64))
        b[pos:pos + len(chunk)] = chunk
    try:
        ref = parse_reference(bytes(b), "fuzz.npz")
    except ReferenceFileError as exc:
        one_line(exc)
        assert str(exc).startswith("fuzz.npz: ")
        return
    _check_loaded(ref)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**30, 10**30)
    | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                max_size=4),
    max_leaves=12)


@FUZZ
@given(data=st.data())
def test_reference_metadata_of_any_value_loads_or_gives_one_error(good_ref, data):
    """One or more metadata values replaced by any JSON value, with a checksum that
    matches (so validation, not the checksum, has to catch it)."""
    ref, _ = good_ref
    meta = json.loads(json.dumps(ref.meta))
    keys = sorted(meta) + ["depends." + k for k in sorted(meta["depends"])]
    for key in data.draw(st.lists(st.sampled_from(keys), min_size=1, max_size=3)):
        value = data.draw(json_values)
        if key.startswith("depends."):
            if isinstance(meta.get("depends"), dict):
                meta["depends"][key[8:]] = value
        elif data.draw(st.booleans()):
            meta[key] = value
        else:
            meta.pop(key, None)
    meta["file_format"] = 2
    meta["sha256"] = checksum(ref.table, ref.mean_pulse, meta)
    try:
        loaded = parse_reference(_npz(ref.table, ref.mean_pulse, meta), "m.npz")
    except ReferenceFileError as exc:
        one_line(exc)
        return
    _check_loaded(loaded)


@pytest.mark.parametrize("device", [None, True, [1, 2], "x", {"gain_wander_db": None},
                                    {"gain_wander_db": "3"}, {"gain_wander_db": 1e300}])
def test_a_device_entry_of_any_value_gives_a_usable_analyzer(good_ref, device):
    """The case the fuzz above found (``device: null``, AttributeError in new_analyzer):
    the optional device figures, whatever they hold, neither break the analyzer nor
    switch on the gain normalisation, except a real wander over its threshold."""
    ref, _ = good_ref
    meta = json.loads(json.dumps(ref.meta))
    meta["device"] = device
    meta["file_format"] = 2
    meta["sha256"] = checksum(ref.table, ref.mean_pulse, meta)
    loaded = parse_reference(_npz(ref.table, ref.mean_pulse, meta), "m.npz")
    an = new_analyzer(config.Config(), loaded)
    assert an.static.normalise == (device == {"gain_wander_db": 1e300})


@FUZZ
@given(table=st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64),
                      min_size=1, max_size=64),
       rows=st.integers(1, 8), cols=st.integers(1, 8))
def test_reference_arrays_of_any_shape_and_value(good_ref, table, rows, cols):
    ref, _ = good_ref
    t = np.resize(np.array(table, dtype=np.float64), (rows, cols))
    m = np.resize(np.array(table, dtype=np.float64), (cols,))
    meta = dict(ref.meta, phase_bins=rows, file_format=2,
                gate_samples=[ref.meta["gate_samples"][0], ref.meta["gate_samples"][0] + cols])
    meta["sha256"] = checksum(t, m, meta)
    try:
        loaded = parse_reference(_npz(t, m, meta), "a.npz")
    except ReferenceFileError as exc:
        one_line(exc)
        assert np.any(~np.isfinite(t)) or np.any(~np.isfinite(m)) or not np.any(t) \
            or np.max(np.abs(t)) > 1e6 or np.max(np.abs(m)) > 1e6, str(exc)
        return
    _check_loaded(loaded)


# -- WAV ---------------------------------------------------------------------------------

@FUZZ
@given(tag=st.sampled_from([1, 3, 0xFFFE, 0, 2, 6, 65535]),
       channels=st.integers(0, 3) | st.integers(0, 65535),
       rate=st.sampled_from([44100, 0, 1, 999, 48000]) | st.integers(0, 2**32 - 1),
       bits=st.sampled_from([8, 16, 24, 32, 64, 0, 12]),
       align_delta=st.integers(-2, 2), n_bytes=st.integers(0, 4000),
       declared_delta=st.sampled_from([0, 0, -1, 1, 10**6, 2**32 - 4001]),
       junk=st.lists(st.tuples(st.binary(min_size=4, max_size=4),
                               st.integers(0, 2**32 - 1)), max_size=3),
       cut=st.none() | st.integers(0, 4100))
def test_any_wav_header_reads_or_gives_one_error(tag, channels, rate, bits, align_delta,
                                                 n_bytes, declared_delta, junk, cut):
    align = max(channels * bits // 8 + align_delta, 0)
    fmt = struct.pack("<HHIIHH", tag, channels, rate, (rate * max(align, 1)) & 0xFFFFFFFF,
                      align & 0xFFFF, bits)
    if tag == 0xFFFE:
        fmt += struct.pack("<HHIH", 22, bits, 0, 3 if bits >= 32 else 1) + bytes(14)
    chunks = b"fmt " + struct.pack("<I", len(fmt)) + fmt
    for cid, size in junk:
        chunks += cid + struct.pack("<I", size) + bytes(min(size, 16))
    declared = (n_bytes + declared_delta) & 0xFFFFFFFF
    chunks += b"data" + struct.pack("<I", declared) + bytes(n_bytes)
    raw = b"RIFF" + struct.pack("<I", len(chunks) + 4) + b"WAVE" + chunks
    if cut is not None:
        raw = raw[:cut]
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "f.wav"
        p.write_bytes(raw)
        try:
            x, fs = read_wav(p)
        except InputError as exc:
            one_line(exc)
            return
    assert x.dtype == np.float64 and x.ndim == 1 and 0 < len(x) <= len(raw)
    assert fs == rate and np.all(np.abs(x[np.isfinite(x)]) <= 1.0 + 1e-12) or tag == 3


# -- YAML and config ---------------------------------------------------------------------

yaml_tokens = st.sampled_from(
    ["audio:", "\n", "  ", " ", "sample_rate: ", "44100", "- ", "[", "]", "{", "}", ",",
     "&a ", "*a", "<<: ", "!!str ", "!!python/object:os.system ", "'", '"', "1e999", ".nan",
     "#", "---\n", "...\n", "? ", ": ", "\t", "\x00", "\ufeff", "é", "9" * 5000, "|\n",
     "daemon:", "  window_s: ", "-1", "true", "null", "~", "mqtt: {host: x}", "%YAML 1.1\n"])


@FUZZ
@given(tokens=st.lists(yaml_tokens, max_size=40) | st.lists(st.text(max_size=20),
                                                            max_size=10))
def test_any_yaml_text_builds_a_config_or_gives_one_error(tokens):
    text = "".join(tokens)
    try:
        data, lines = parse_yaml(text, source="f.yaml")
        config.from_mapping(data, source="f.yaml", lines=lines)
    except ConfigError as exc:
        one_line(exc)


schema_keys = [k for k, _ in config.iter_fields()]


@FUZZ
@given(values=st.dictionaries(st.sampled_from(schema_keys) | st.text(max_size=10),
                              json_values, max_size=6))
def test_any_config_values_validate_or_give_one_error(values):
    data: dict = {}
    for key, value in values.items():
        sec, _, name = key.rpartition(".")
        if sec:
            data.setdefault(sec, {})
            if isinstance(data[sec], dict):
                data[sec][name] = value
        else:
            data[name] = value
    try:
        cfg = config.from_mapping(data, source="f.yaml")
    except ConfigError as exc:
        one_line(exc)
        return
    for key, _ in config.iter_fields():
        v = cfg
        for part in key.split("."):
            v = getattr(v, part)
        assert not (isinstance(v, float) and not math.isfinite(v)), key


_SCENE_KEYS = ["name", "room", "room.vertices", "room.reflection", "sensor", "fan",
               "fan.centre", "fan.blades", "fan.blade_length_m", "fan.hub_radius_m",
               "fan.start_angle_deg", "fan.reflectivity", "coupling_gain", "schedule", "x"]
points = st.lists(st.lists(st.floats(-1e3, 1e3) | st.sampled_from([math.nan, math.inf]),
                           min_size=2, max_size=3), max_size=8)


@FUZZ
@given(changes=st.dictionaries(st.sampled_from(_SCENE_KEYS), json_values | points,
                               max_size=4))
def test_any_scene_values_validate_or_give_one_error(changes):
    """The shipped scene with some values replaced by anything."""
    data, lines = parse_yaml(Path(SCENE).read_text(), source="s.yaml", key="--scene")
    for key, value in changes.items():
        sec, _, name = key.rpartition(".")
        target = data.get(sec) if sec else data
        if isinstance(target, dict):
            target[name] = value
    try:
        Scene.from_mapping(data, source="s.yaml", lines=lines)
    except ConfigError as exc:
        one_line(exc)


@FUZZ
@given(raw=st.binary(max_size=300) | st.lists(yaml_tokens, max_size=30).map(
    lambda t: "".join(t).encode("utf-8", "surrogatepass")))
def test_check_config_cli_exits_0_or_2_on_any_bytes(raw):
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "c.yaml"
        p.write_bytes(raw)
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = cli.main(["check-config", "--config", str(p)])
    assert rc in (0, 2)
    if rc == 2:
        lines = err.getvalue().splitlines()
        assert len(lines) == 1 and lines[0].startswith("bladesonar check-config: error: ")
        assert len(lines[0]) <= MAX_MESSAGE + 200
