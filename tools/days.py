"""Simulated days of ordinary use through the live per-pulse pipeline, and their scores
(tools/bench_day, tools/trace_day.py).

Two kinds of day: the tuned one (:func:`day`: the paper room, a 0.45 Hz reference,
10-12 dB, 40 ppm) and a random scene's (:func:`random_day`: sim/random_scene.py, a room,
fan, device and reference drawn from the seed). :func:`run_day` pushes a day through
:class:`LiveAnalyzer` as the daemon does and scores it against the schedule's truth.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bladesonar import config
from bladesonar.errors import EstimationError, InputError
from bladesonar.io.scene_file import load_scene
from bladesonar.live import LiveAnalyzer, capture_pulses
from bladesonar.reference_build import (
    NEARER_ADVICE,
    PLACE_ADVICE,
    Reference,
    build_reference,
    folds_multipath,
    unfolding_pri,
)
from bladesonar.runtime_report import TRANSITION_TARGETS_S
from bladesonar.sim import random_scene
from bladesonar.sim.render import Simulator, simulate
from bladesonar.sim.schedule import Schedule, ordinary_use, parse
from bladesonar.sim.score import (
    Score,
    score_events,
    score_gaps,
    score_state,
    true_time,
    truth_events,
)

#: the capture clock's drift on a tuned day (the issue's test condition)
DRIFT_PPM = 40.0
#: The fan speed a user picks when the reference asks for another one (commensurate
#: with the PRF): a few percent faster, as the reference's words say.
OTHER_SPEED = 1.04
HERE = Path(__file__).resolve().parent.parent


#: How many times the sweep's user does what a reference advises before living with the
#: last one: a user moves the device again while `reference` still asks for it, and
#: changes a setting it names (the PRI, the volume, the fan's speed) again while it asks.
#: Moves and settings count apart: a setting changed first (since 2026-11-30 the PRI for
#: a fan 2.5 m away or more) used to leave one move fewer, and a room that needed five
#: moves was left at a place its reference still advised against (spent 2900004).
ADVICE_TAKEN = 5


def day(hours: float, seed: int, block_pulses: int = 1,
        snr_db: tuple[float, float] = (10.0, 12.0), drift_ppm: float = DRIFT_PPM
        ) -> tuple[config.Config, Schedule, Simulator, LiveAnalyzer, float]:
    """bench_day's tuned day: (config, schedule, simulator, live pipeline analysing blocks
    of ``block_pulses`` capture periods, SNR in dB). The SNR is drawn from ``snr_db`` (the
    issue's 10-12 dB by default: the same draw, so a seed gives the same day)."""
    rng = np.random.default_rng(seed)
    cfg = config.Config()
    scene = load_scene(str(HERE / "config/scenes/paper-room.yaml"))
    sch = parse(ordinary_use(rng, hours * 3600.0))
    x, _ = simulate(scene, cfg, 20.0, schedule="ccw:0.45:20", seed=seed, snr_db=20.0)
    ref = build_reference(x, cfg, "ccw")
    snr = float(rng.uniform(*snr_db))
    sim = Simulator(scene, cfg, sch, snr_db=snr, seed=seed + 1, drift_ppm=drift_ppm,
                    include_paths=False)
    return cfg, sch, sim, LiveAnalyzer(cfg, ref, block_pulses=block_pulses), snr


def _half_volume(cfg: config.Config) -> config.Config:
    """What the clipping warning and refusal ask of a user: half the playback volume."""
    return config.replace(cfg, waveform={"amplitude": cfg.waveform.amplitude / 2})


def random_day(hours: float, seed: int, block_pulses: int = 1, dims: int = 2,
               stay: bool = False) -> tuple[config.Config, Schedule, Simulator, LiveAnalyzer,
                          random_scene.SceneDraw | random_scene.DayDraw3D]:
    """A random scene's day (sim/random_scene.py; ``dims`` 3: a 3-D box room with pitched
    blades, ``draw_day_3d``, rendered in the same streamed chunks): the reference is
    learned in the same room, at the same SNR and drift, from 20 s of the fan at the
    reference speed, as the daemon learns it. What the reference says is done as a user
    would do it, and it is learned again: when the fan's wall bounces fold past one PRI,
    with the PRI the warning names; when echoes clip (warned, or refused for too few
    pulses left), at half the playback volume; when
    the speed is commensurate with the PRF (warned, or refused), at another fan speed,
    OTHER_SPEED times the last; when the place tells the fan's directions apart too
    weakly (warned: ``PLACE_ADVICE``), with the device moved as the warning asks
    (``random_scene.moved``), and when it shows the fan too little to follow (warned:
    ``NEARER_ADVICE``), nearer the fan (``random_scene.nearer``; both 2-D scenes only,
    and not with ``stay``: the device left where it was drawn). Settings and moves are
    each taken up to ``ADVICE_TAKEN`` times."""
    cfg0 = config.Config()
    if dims not in (2, 3):
        raise ValueError(f"dims {dims!r}: give 2 (floor-plan scenes) or 3 (box rooms)")
    dr: random_scene.SceneDraw | random_scene.DayDraw3D = (
        random_scene.draw(seed, cfg0.prf_hz) if dims == 2
        else random_scene.draw_day_3d(seed, cfg0.prf_hz))
    cfg = config.replace(cfg0, scene={"blades": dr.blades})
    sch = parse(dr.schedule(hours * 3600.0))
    def learn(cfg: config.Config, rate_hz: float) -> Reference:
        x, _ = simulate(dr.scene, cfg, random_scene.REFERENCE_S,
                        schedule=f"{dr.ref_direction}:{rate_hz:.4f}:60",
                        seed=seed, snr_db=dr.snr_db, drift_ppm=dr.drift_ppm,
                        nuisances=dr.nuisances, include_paths=False)
        return build_reference(x, cfg, dr.ref_direction)

    rate_hz = dr.ref_rate_hz
    ref: Reference | None = None
    changes = moves = 0             # settings changed and places moved to on advice
    while True:
        try:
            ref = learn(cfg, rate_hz)
        except EstimationError as e:
            if changes == ADVICE_TAKEN or "different fan speed" not in str(e):
                raise
            ref, rate_hz, changes = None, rate_hz * OTHER_SPEED, changes + 1
            continue
        except InputError as e:
            # refused for echoes that clip (too few pulses left): as the warning, half
            # the playback volume
            if changes == ADVICE_TAKEN or "lower the playback volume" not in str(e):
                raise
            ref, cfg, changes = None, _half_volume(cfg), changes + 1
            continue
        warnings = ref.meta["warnings"]
        if changes < ADVICE_TAKEN:
            if folds_multipath(ref.gate, ref.meta["target_range_m"]):
                cfg = config.replace(cfg, waveform={
                    "pri_samples": unfolding_pri(cfg, ref.meta["target_range_m"])})
                changes += 1
                continue
            if any("lower the playback volume" in w for w in warnings):
                cfg, changes = _half_volume(cfg), changes + 1
                continue
            if any("another fan speed" in w for w in warnings):
                rate_hz, changes = rate_hz * OTHER_SPEED, changes + 1
                continue
        if moves < ADVICE_TAKEN and not stay and isinstance(dr, random_scene.SceneDraw) and (
                (nearer := any(NEARER_ADVICE in w for w in warnings))
                or any(PLACE_ADVICE in w for w in warnings)):
            # the match-share advice first: a place that shows the fan too little to
            # follow cannot be helped by wall echoes that tell the directions apart
            there = (random_scene.nearer if nearer else random_scene.moved)(
                dr, len(dr.moved_from))
            if there is not dr:
                dr, moves = there, moves + 1
                continue
        break               # (the configuration the reference was learned with)
    assert ref is not None
    sim = Simulator(dr.scene, cfg, sch, snr_db=dr.snr_db, seed=seed + 1,
                    drift_ppm=dr.drift_ppm, nuisances=dr.nuisances, include_paths=False)
    return cfg, sch, sim, LiveAnalyzer(cfg, ref, block_pulses=block_pulses), dr


def run_day(cfg: config.Config, sch: Schedule, sim: Simulator, live: LiveAnalyzer,
            seconds: float, *, drift_ppm: float, ref_sign: int, block_pulses: int = 1,
            ramp_max_hz_s: float = 0.1, progress: bool = False) -> tuple[Score, dict[str, Any]]:
    """Push ``seconds`` of the day through ``live`` and score it: (the score, run facts:
    wall and CPU seconds). States are scored where the daemon publishes them (after each
    block of ``block_pulses``), against the fan at that moment; the rate error on ramps
    counts where the true rate changes at up to ``ramp_max_hz_s``."""
    pri, fs = cfg.waveform.pri_samples, cfg.audio.sample_rate
    events: list[tuple[str, float]] = []
    states: list[tuple[float, str, str | None, float | None]] = []
    t0, c0 = time.time(), time.process_time()
    every = int(6.0 * fs) // pri        # progress every 6 s of the day
    for pos, x in capture_pulses((xs for xs, _ in sim.chunks(seconds)), pri):
        est = live.push(x, pos - pri)
        if progress and (pos // pri) % every == 0:
            print(f"\r{pos / fs / 60:6.1f} of {seconds / 60:.0f} simulated minutes", end="",
                  file=sys.stderr, flush=True)
        if est is None or (block_pulses > 1 and (pos // pri) % block_pulses):
            continue    # (in blocks, the daemon publishes what it has after each block)
        states.append((pos / fs, est.direction.value, est.rotation, est.rate_hz))
        events += [(e.kind, e.t_s) for e in live.take_events()]
    wall, cpu = time.time() - t0, time.process_time() - c0
    if progress:
        print(file=sys.stderr)
    # stream times (the capture clock's) to the schedule's (sim.score.true_time)
    events = [(kind, true_time(t_ev, drift_ppm)) for kind, t_ev in events]
    # a truth event within the longest latency allowed (a stop's) of the end counts only
    # if it was found: it is not yet due
    # a fan set below 0.15 Hz (MOVING_HZ) but at twice the rate floor or more changes
    # state without an event the truth can time: such events are optional
    low = 2.0 * cfg.tracking.rate_floor_hz
    score = score_events(truth_events(sch, seconds, low_hz=low), events,
                         due_by=seconds - max(TRANSITION_TARGETS_S.values()))
    times = true_time(np.array([s[0] for s in states]), drift_ppm)
    truth = sch.rate_at(times)
    slope = np.abs(sch.rate_at(times + 0.05) - sch.rate_at(times - 0.05)) / 0.1
    ramping = (slope > 1e-6) & (slope <= ramp_max_hz_s + 1e-9)
    for tt, (_, d, rot, hz), r, rp in zip(times, states, truth, ramping, strict=True):
        score_state(score, float(tt), float(r), d, rot, hz, ref_sign=ref_sign,
                    ramping=bool(rp))
    score_gaps(score, list(times), [s[1] for s in states], truth)
    return score, {"wall_s": wall, "cpu_s": cpu}
