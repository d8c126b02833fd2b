"""``audio.backend: sim``: the daemon's audio interface fed by the in-process scene simulator.

The demo and the self-test run the real daemon with no sound card. Periods are rendered
on demand in the consumer's thread (no audio thread to starve) and, with
``sim.realtime``, handed out no sooner than a sound card would capture them: period k is
complete at ``t0 + (k + 1) * pri / fs``. A consumer that falls further behind than
``audio.ring_pulses`` loses the oldest periods, counted and flagged, as on a device.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ConfigError
from .audio import PulseBlock

if TYPE_CHECKING:
    from ..config import Config

log = logging.getLogger(__name__)

#: Length of one simulated run (seconds); a new run (new time base) follows, flagged.
RUN_SECONDS = 1.0e6
#: At most this much of the schedule sets the noise level (the SNR reference power).
SNR_REFERENCE_S = 120.0


class SimAudio:
    """Implements ``AudioIO`` on ``bladesonar.sim.render.Simulator``."""

    def __init__(self, cfg: Config, *, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.cfg = cfg
        self.pri = int(cfg.waveform.pri_samples)
        self.fs = float(cfg.audio.sample_rate)
        self.clock, self.sleep = clock, sleep
        #: what was found and chosen (backends.audio_choice; empty when built directly)
        self.choice: dict[str, Any] = {}
        self._chunks: Iterator[tuple[np.ndarray, list[dict[str, Any]]]] | None = None
        self._noise_rng: np.random.Generator | None = None
        self.sigma = 0.0
        self._t0 = 0.0
        self._k = 0                 # next period to hand out
        self._disc = False
        self.runs = 0
        self.periods_read = 0
        self.ring_overflows = 0

    def start(self) -> None:
        from ..io.scene_file import load_any_scene
        from ..sim.render import Simulator

        c = self.cfg
        try:
            self._scene = load_any_scene(c.path(c.sim.scene))   # 2-D or 3-D
        except ConfigError as exc:
            if exc.key != "--scene":
                raise
            raise ConfigError("sim.scene", c.sim.scene, exc.allowed) from exc
        self._make: Callable[[int], Simulator] = lambda seed: Simulator(
            self._scene, c, c.sim.schedule, snr_db=None, seed=seed)
        # noise level: the simulator's SNR definition over the first stretch of the schedule
        ref = Simulator(self._scene, c, c.sim.schedule, snr_db=c.sim.snr_db, seed=c.sim.seed)
        span = min(sum(s.seconds for s in ref.schedule.segments), SNR_REFERENCE_S)
        self.sigma = float(ref.prepare(max(span, 1.0))["snr"]["noise_sigma"])
        self._new_run()
        self._t0 = self.clock()
        sched = c.sim.schedule   # a long one (a simulated day) is cut in the log
        if len(sched) > 200:
            sched = f"{sched[:160]}... ({len(ref.schedule.segments)} segments)"
        log.info("simulated audio: scene %s, schedule %s, SNR %g dB (noise sigma %.3g), %s",
                 c.sim.scene, sched, c.sim.snr_db, self.sigma,
                 "paced in real time" if c.sim.realtime else "as fast as possible")

    def _new_run(self) -> None:
        seed = self.cfg.sim.seed + self.runs
        self._chunks = iter(self._make(seed).chunks(RUN_SECONDS, self.pri))
        self._noise_rng = np.random.default_rng([seed, 0x5A])
        self._disc = self.runs > 0
        self.runs += 1

    def _render(self) -> np.ndarray:
        assert self._chunks is not None and self._noise_rng is not None
        try:
            x, _ = next(self._chunks)
        except StopIteration:
            self._new_run()
            x, _ = next(self._chunks)
        if self.sigma > 0:
            x = x + self.sigma * self._noise_rng.standard_normal(len(x))
        return x

    def read_pulses(self, n: int, timeout: float) -> list[PulseBlock]:
        if self._chunks is None:
            raise RuntimeError("SimAudio.read_pulses before start()")
        first = timeout
        if self.cfg.sim.realtime and n > 1:
            # one wait, until the n-th period is complete (as the ALSA ring does), then
            # what is complete by then
            wait = self._t0 + (self._k + n) * self.pri / self.fs - self.clock()
            if wait > 0:
                self.sleep(min(wait, max(timeout, 0.0)))
            first = 0.0
        out: list[PulseBlock] = []
        b = self.read_pulse(first)
        while b is not None:
            out.append(b)
            if len(out) >= n:
                break
            b = self.read_pulse(0.0)
        return out

    def read_pulse(self, timeout: float) -> PulseBlock | None:
        if self._chunks is None:
            raise RuntimeError("SimAudio.read_pulse before start()")
        if self.cfg.sim.realtime:
            now = self.clock()
            due = self._t0 + (self._k + 1) * self.pri / self.fs
            if due > now:
                if due - now > timeout:
                    self.sleep(max(timeout, 0.0))
                    return None
                self.sleep(due - now)
            else:
                captured = math.floor((now - self._t0) * self.fs / self.pri)
                behind = captured - self._k - self.cfg.audio.ring_pulses
                for _ in range(max(behind, 0)):      # the ring overflowed: oldest lost
                    self._render()
                    self._k += 1
                    self.ring_overflows += 1
                    self._disc = True
        x = self._render()
        done = self._t0 + (self._k + 1) * self.pri / self.fs if self.cfg.sim.realtime else None
        block = PulseBlock(x, self._k * self.pri, self._disc, done)
        self._k += 1
        self._disc = False
        self.periods_read += 1
        return block

    def stats(self) -> dict[str, int]:
        return {"xruns_playback": 0, "xruns_capture": 0, "ring_overflows": self.ring_overflows,
                "periods_written": self.periods_read, "periods_read": self.periods_read,
                "periods_delivered": self.periods_read}

    def stop(self, timeout: float = 2.0) -> None:
        self._chunks = None
