"""A random scene's reference learned as the daemon learns it, a live capture of it, and a
schedule of that scene rendered for analyze (tests of traced held-out scenes)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np

from bladesonar import config
from bladesonar.live import capture_pulses
from bladesonar.reference_build import Reference, build_reference
from bladesonar.sim import random_scene
from bladesonar.sim.render import Simulator, simulate
from bladesonar.sim.schedule import Schedule, parse
from bladesonar.sim.score import true_time


def learned(dr: random_scene.SceneDraw, cfg: config.Config, seed: int) -> Reference:
    """Scene ``seed``'s reference with ``cfg``, as the daemon learns it: 20 s at the
    reference speed, at the scene's SNR, drift and nuisances."""
    x, _ = simulate(dr.scene, cfg, random_scene.REFERENCE_S,
                    schedule=f"{dr.ref_direction}:{dr.ref_rate_hz:.4f}:60", seed=seed,
                    snr_db=dr.snr_db, drift_ppm=dr.drift_ppm, nuisances=dr.nuisances,
                    include_paths=False)
    return build_reference(x, cfg, dr.ref_direction)


def streamed(dr: random_scene.SceneDraw | random_scene.DayDraw3D, cfg: config.Config,
             schedule: str | Schedule, seed: int) -> Simulator:
    """A live capture of scene ``dr`` turning by ``schedule``, at the scene's SNR, drift
    and nuisances, noise drawn from ``seed``."""
    sch = parse(schedule) if isinstance(schedule, str) else schedule
    return Simulator(dr.scene, cfg, sch, snr_db=dr.snr_db, seed=seed,
                     drift_ppm=dr.drift_ppm, nuisances=dr.nuisances, include_paths=False)


def learned_and_rendered(seed: int, schedule: str, seconds: float
                         ) -> tuple[random_scene.SceneDraw, config.Config, Reference,
                                    np.ndarray]:
    """Scene ``seed``'s draw, its config, its reference (20 s at the reference speed, at
    the scene's SNR, drift and nuisances) and ``schedule`` rendered over ``seconds``
    with another noise draw (seed + 7)."""
    dr = random_scene.draw(seed)
    cfg = config.replace(config.Config(), scene={"blades": dr.blades})
    ref = learned(dr, cfg, seed)
    y, _ = simulate(dr.scene, cfg, seconds, schedule=schedule, seed=seed + 7,
                    snr_db=dr.snr_db, drift_ppm=dr.drift_ppm, nuisances=dr.nuisances,
                    include_paths=False)
    return dr, cfg, ref, y


def days_module() -> ModuleType:
    """tools/days.py, the module tools/bench_day runs its days with (the tests of a day
    as the bench streams it: the same schedule, reference and advice taken)."""
    path = Path(__file__).resolve().parent.parent / "tools" / "days.py"
    spec = importlib.util.spec_from_file_location("days", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("days", mod)
    spec.loader.exec_module(mod)
    return mod


def streamed_day(seed: int, until_s: float, hours: float = 0.4, block_pulses: int = 1
                 ) -> tuple[Schedule, list[tuple[float, str]], list[tuple[float, str]]]:
    """Random room ``seed``'s day as tools/bench_day streams it (:func:`days_module`),
    through the daemon's pipeline to ``until_s``: its schedule, the events and the
    published directions, each at the schedule's (true) time. ``block_pulses``: the
    daemon's blocks (8 as configured: the same states and events, tests/test_live.py,
    in less time; a state is then published per block)."""
    cfg, sch, sim, live, dr = days_module().random_day(hours, seed, block_pulses)
    fs = cfg.audio.sample_rate
    events: list[tuple[float, str]] = []
    states: list[tuple[float, str]] = []
    for pos, x in capture_pulses((xs for xs, _ in sim.chunks(hours * 3600.0)), live.pri):
        if pos / fs > until_s:
            break
        est = live.push(x, pos - live.pri)
        t = true_time(pos / fs, dr.drift_ppm)
        events += [(t, e.kind.value) for e in live.take_events()]
        if est is not None:
            states.append((t, est.direction.value))
    return sch, events, states
