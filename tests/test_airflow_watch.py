"""The daemon's live airflow pieces in closed form: the rolling window against plain
concatenation, when a measurement is due, and the contradiction rule's timing (sustained
for SUSTAIN_S, cleared by an agreement or CLEAR_S without a contradiction)."""

from __future__ import annotations

import numpy as np
import pytest

from bladesonar import config
from bladesonar.airflow_recording import WindowFigures
from bladesonar.dsp.airflow import Airflow
from bladesonar.service import airflow_watch as aw


def test_the_window_keeps_the_last_samples_of_an_unbroken_capture():
    rng = np.random.default_rng(1)
    w = aw.SampleWindow(1000)
    stream = rng.standard_normal(5000).astype(np.float32)
    pos = 0
    for n in (300, 450, 1297, 7, 1000, 946):
        w.add(stream[pos:pos + n], pos)
        pos += n
        want = stream[max(0, pos - 1000):pos]
        assert np.array_equal(w.samples(), want.astype(np.float64))
    assert w.full
    # a gap (lost samples) or a flagged discontinuity starts it afresh
    w.add(stream[pos + 10:pos + 110], pos + 10)
    assert not w.full and np.array_equal(w.samples(), stream[pos + 10:pos + 110])
    w.add(stream[:50], pos + 110, discontinuity=True)
    assert np.array_equal(w.samples(), stream[:50])
    with pytest.raises(ValueError, match="at least 1"):
        aw.SampleWindow(0)


def _figs(word: str, turn: str | None) -> WindowFigures:
    t = {"down": -9.0, "up": 9.0}.get(word, 1.0)
    return WindowFigures(Airflow(word, 0.99 if turn else 0.3, t, t / 10, 400, "r", 3), turn)


def _watch() -> aw.AirflowWatch:
    return aw.AirflowWatch(config.from_mapping({"audio": {"sample_rate": 8000}}))


def _advance(w: aw.AirflowWatch, seconds: float) -> None:
    n = int(round(seconds * w.fs))
    w.add(np.zeros(n), w.samples_seen)


def test_a_measurement_is_due_once_the_window_is_full_then_every_so_often():
    w = _watch()
    _advance(w, aw.WINDOW_S - 1)
    assert w.due() is None
    _advance(w, 1)
    x = w.due()
    assert x is not None and len(x) == aw.WINDOW_S * w.fs
    w.submitted(learning=False)
    _advance(w, aw.EVERY_S - 1)
    assert w.due() is None
    _advance(w, 1)
    assert w.due() is not None
    w.submitted(learning=True)
    _advance(w, aw.EVERY_LEARNING_S)
    assert w.due() is not None


def test_the_state_keys_and_their_freshness():
    w = _watch()
    assert w.fields() == {"airflow": "unknown", "airflow_confidence": None}
    _advance(w, 12)
    w.took(_figs("up", "cw"), None, None)
    assert w.fields() == {"airflow": "up", "airflow_confidence": 0.99}
    _advance(w, aw.KEEP_S + 1)       # nothing measured since (a stalled worker)
    assert w.fields()["airflow"] == "unknown"


def test_a_contradiction_is_a_status_only_when_sustained_and_clears_when_it_stops():
    w = _watch()
    _advance(w, 12)
    # the fan turns cw by the airflow (up); the fingerprint says ccw
    t0 = w.now
    for k in range(4):
        w.took(_figs("up", "cw"), None, "ccw")
        assert w.contradiction.active is (w.now - t0 >= aw.SUSTAIN_S), k
        if k < 3:
            assert w.contradiction_detail("ccw") is None
            _advance(w, aw.EVERY_S)
    assert w.contradiction.active and w.now - t0 == aw.SUSTAIN_S
    d = w.contradiction_detail("ccw")
    assert d is not None
    for part in ("is up", "confidence 0.99", "t +9.0", "means cw", "says ccw",
                 "reference direction ccw", f"for {aw.SUSTAIN_S:.0f} s", "set it to cw"):
        assert part in d, (part, d)
    # measurements that cannot compare (airflow unknown) keep it for CLEAR_S, then clear
    last = w.now
    _advance(w, aw.EVERY_S)
    w.took(_figs("unknown", None), None, "ccw")
    assert w.contradiction.active
    _advance(w, aw.CLEAR_S - aw.EVERY_S)
    w.took(_figs("unknown", None), None, "ccw")
    assert w.now - last == aw.CLEAR_S and not w.contradiction.active
    # a run broken by an unknown starts again; a confident agreement clears at once
    t1 = w.now
    w.took(_figs("up", "cw"), None, "ccw")
    _advance(w, aw.EVERY_S)
    w.took(_figs("unknown", None), None, "ccw")
    for _ in range(3):
        _advance(w, aw.EVERY_S)
        w.took(_figs("up", "cw"), None, "ccw")
    assert w.now - t1 > aw.SUSTAIN_S and not w.contradiction.active
    _advance(w, aw.EVERY_S)
    w.took(_figs("up", "cw"), None, "ccw")
    assert w.contradiction.active
    w.took(_figs("up", "cw"), None, "cw")
    assert not w.contradiction.active and w.contradiction_detail("ccw") is None
    # no fingerprint rotation (stopped, unknown, no reference): never a contradiction
    c = aw.Contradiction()
    for t in range(0, 400, 30):
        assert not c.update(float(t), None)
