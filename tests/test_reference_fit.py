"""reference_fit.FitWatch against closed forms, and the reference's live file operations
(io/reference.py, service/learner.py) on real files."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bladesonar import config
from bladesonar.errors import BladesonarError, EstimationError, ReferenceFileError
from bladesonar.io.reference import (
    forget_reference,
    keep_previous,
    previous_path,
    read_reference,
    write_reference,
)
from bladesonar.reference_fit import FIT_NOMINAL, HYSTERESIS, FitWatch
from bladesonar.service import learner


def feed(w: FitWatch, t0: float, seconds: int, quality: float, moving: bool = True) -> float:
    for i in range(seconds):
        w.update(t0 + i, moving, quality)
    return t0 + seconds


def test_fit_is_one_where_the_room_fits_and_needs_half_a_span():
    w = FitWatch(0.8, stale_fit=0.6, span_s=60)
    t = feed(w, 0.0, 30, 0.8 * FIT_NOMINAL)
    assert w.fit is None                      # 29 s of moving time: less than half
    t = feed(w, t, 5, 0.8 * FIT_NOMINAL)
    assert w.fit == pytest.approx(1.0) and not w.stale


def test_stale_after_a_full_span_below_the_threshold_and_back_with_hysteresis():
    w = FitWatch(0.8, stale_fit=0.6, span_s=60)
    t = feed(w, 0.0, 40, 0.5 * 0.8 * FIT_NOMINAL)
    assert w.fit == pytest.approx(0.5) and not w.stale      # not a full span yet
    t = feed(w, t, 30, 0.5 * 0.8 * FIT_NOMINAL)
    assert w.stale
    # back at 0.65 of the promise: above stale_fit, below stale_fit + hysteresis
    t = feed(w, t, 70, 0.65 * 0.8 * FIT_NOMINAL)
    assert w.fit == pytest.approx(0.65) and w.stale
    t = feed(w, t, 70, (0.6 + HYSTERESIS + 0.01) * 0.8 * FIT_NOMINAL)
    assert not w.stale


def test_a_stopped_fan_and_pauses_count_for_nothing():
    w = FitWatch(0.8, stale_fit=0.6, span_s=60)
    t = feed(w, 0.0, 61, 0.8 * FIT_NOMINAL)
    t = feed(w, t, 600, 0.0, moving=False)   # at rest: the match quality says nothing
    assert w.fit == pytest.approx(1.0) and not w.stale
    w.update(t + 3600, True, 0.0)            # an hour's gap counts as 10 s at most
    assert w.moving_s <= 60 and w.fit is not None and w.fit > 0.8
    w.update(t + 3601, True, math.nan)       # no figure: ignored
    assert w.fit > 0.8


def test_fit_watch_refuses_what_it_cannot_use():
    with pytest.raises(ValueError, match="ref_quality must be positive, got 0"):
        FitWatch(0.0, stale_fit=0.6, span_s=60)
    with pytest.raises(ValueError, match="span_s must be positive, got -1"):
        FitWatch(0.8, stale_fit=0.6, span_s=-1)


# -- the reference's files -----------------------------------------------------------------


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    """A reference learned by the worker's job from 8 s of the simulated fan."""
    from bladesonar.io.scene_file import load_scene
    from bladesonar.sim.render import simulate
    from loopback import SCENE

    cfg = config.Config()
    x, _ = simulate(load_scene(SCENE), cfg, 8.0, schedule="ccw:0.45:8", seed=2, snr_db=20.0)
    path = tmp_path_factory.mktemp("ref") / "state" / "reference.npz"
    info = learner.learn(x, cfg, "unknown", path)
    return cfg, x, path, info


def test_learn_job_writes_a_valid_reference_and_keeps_the_old_one(learned, tmp_path):
    cfg, x, path, info = learned
    ref, digest = read_reference(path)
    assert digest[:12] == info["id"] and ref.meta["direction"] == "unknown"
    assert info["quality"] >= cfg.reference.min_quality
    p = tmp_path / "reference.npz"
    p.write_bytes(path.read_bytes())
    again = learner.learn(x, cfg, "cw", p, why="auto")
    assert read_reference(p)[0].meta["direction"] == "cw" and again["direction"] == "cw"
    # the file says why the daemon learned it (the keeper learns its own again at
    # another speed, not a person's): the default is a person's command
    assert ref.meta["learned_by"] == "command"
    assert read_reference(p)[0].meta["learned_by"] == "auto"
    assert read_reference(previous_path(p))[1] == digest        # the old one, whole
    assert sorted(q.name for q in tmp_path.iterdir()) == ["reference.npz",
                                                         "reference.npz.previous"]


def test_learn_job_refuses_a_recording_without_a_steady_fan(learned, tmp_path):
    cfg, x, _, _ = learned
    noise = np.random.default_rng(1).normal(0, 1e-3, len(x))
    with pytest.raises(BladesonarError) as e:
        learner.learn(noise, cfg, "unknown", tmp_path / "reference.npz")
    assert str(e.value) and not (tmp_path / "reference.npz").exists()
    strict = config.replace(cfg, reference={"min_quality": 0.99})
    with pytest.raises(EstimationError, match=r"explains only 0\.\d\d .*min_quality 0\.99"):
        learner.learn(x, strict, "unknown", tmp_path / "reference.npz")
    assert not (tmp_path / "reference.npz").exists()


def test_direction_and_forget_jobs(learned, tmp_path):
    _, _, path, _ = learned
    p = tmp_path / "reference.npz"
    p.write_bytes(path.read_bytes())
    before = read_reference(p)
    digest = learner.set_direction(p, "ccw")
    ref, got = read_reference(p)
    assert got == digest and ref.meta["direction"] == "ccw"
    assert np.array_equal(ref.table, before[0].table)          # only the direction
    kept = learner.forget(p)
    assert not p.exists() and kept == str(previous_path(p))
    assert read_reference(previous_path(p))[1] == digest
    assert forget_reference(p) is None                          # nothing left: no error
    assert keep_previous(tmp_path / "absent.npz") is None


def test_write_errors_name_the_file_and_the_fix(learned, tmp_path):
    _, _, path, _ = learned
    ref, _ = read_reference(path)
    blocker = tmp_path / "state"
    blocker.write_text("a file where the state folder should be")
    with pytest.raises(ReferenceFileError, match=r"state/reference.npz: cannot be written "
                                                 r".*writable path"):
        write_reference(ref, blocker / "reference.npz")
    assert blocker.read_text().startswith("a file")


def test_jobs_run_one_at_a_time_off_the_caller(learned):
    jobs = learner.ReferenceJobs()
    import threading

    gate = threading.Event()
    assert jobs.submit("a", gate.wait, 5)
    assert jobs.busy == "a" and not jobs.submit("b", lambda: 1)
    gate.set()
    assert jobs.wait_idle(5)
    assert [(r.name, r.ok) for r in jobs.poll()] == [("a", True)]
    assert jobs.submit("c", learner.forget, "/nonexistent-dir/x/reference.npz")
    assert jobs.wait_idle(5)
    (r,) = jobs.poll()
    assert r.ok and r.value is None
    assert jobs.submit("d", lambda: 1 / 0)
    assert jobs.wait_idle(5)
    (r,) = jobs.poll()
    assert not r.ok and "ZeroDivisionError" in str(r.error)
    jobs.close()
    assert not jobs.submit("e", lambda: 1)
