"""The daemon's per-pulse pipeline: capture periods in, the current estimate out (pure).

The same stages as ``offline.analyze`` (aligner -> static removal -> match -> track ->
decide), fed one capture period at a time. What the offline path gets from a whole file
it gets here from a warm-up: the running static estimate is primed from the first
``analysis.static_window_s`` of valid pulses before any answer is given.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from .analyzer import PulseAnalyzer, WarmStart, device_figures, new_aligner
from .answer import WAYS, Decision, Estimate, RateState
from .config import Config
from .dsp.pulses import DROPOUT, OK, AlignedPulses
from .reference_build import Reference
from .transitions import Event

#: Samples beyond the gate that the fractional-shift interpolator reads.
_INTERP_MARGIN = 32
#: Longest time a changing rate is predicted ahead, s (the answer is at most a block of
#: capture periods and the aligner's one PRI behind the present; beyond that something
#: else held it up, and the prediction is left at this).
MAX_AHEAD_S = 0.5


def predicted(d: Decision, ahead_s: float, floor_hz: float) -> Decision:
    """A changing rate as it is ``ahead_s`` seconds after the pulse it was decided on:
    its own rate of change carried forward (the follower's constant-change model), never
    below ``floor_hz`` (a direction is claimed, so the fan turns at least that fast). A
    settled rate, and any other answer, is returned as it is. A pulse is analysed once
    the next pulse's edge is in, and the daemon gathers capture periods in blocks: on a
    0.08 Hz/s spin-up the rate decided on the pulse was 0.008 Hz behind the fan when it
    was handed over one period at a time, 0.015 Hz in blocks of 8 (tests/test_live.py)."""
    if d.rate_state != RateState.CHANGING or d.rate_hz is None or d.rate_change_hz_s is None \
            or d.relative_rate is None or not ahead_s > 0:
        return d
    change = d.rate_change_hz_s
    if not math.isfinite(change):
        return d
    hz = max(d.rate_hz + change * min(ahead_s, MAX_AHEAD_S), floor_hz)
    rel = d.relative_rate * hz / d.rate_hz if d.rate_hz > 0 else d.relative_rate
    return replace(d, rate_hz=hz, relative_rate=rel, rpm=hz * 60.0)


def capture_pulses(chunks: Iterable[np.ndarray], pri: int) -> Iterator[tuple[int, np.ndarray]]:
    """A capture stream in chunks of any size, cut into PRI-long blocks as the daemon
    pushes them: (the stream sample after the block, the block)."""
    pos, buf = 0, np.zeros(0)
    for xs in chunks:
        buf = np.concatenate([buf, xs])
        n = len(buf) // pri
        for i in range(n):
            pos += pri
            yield pos, buf[i * pri:(i + 1) * pri]
        buf = buf[n * pri:]


class LiveAnalyzer:
    """Streaming analysis for the service; one instance per (config, reference).

    ``block_pulses``: capture periods gathered before they are analysed together (the
    daemon's ``daemon.block_pulses``). The numpy work of a block costs about the same
    for 1 pulse as for 8, so the CPU per pulse falls with it (measured here, tight loop:
    0.88 ms per pulse one at a time, 0.46 at 4, 0.38 at 8); the answer of a pulse comes
    that many PRIs later at most. Decisions fall on the same pulses whatever the blocks.
    """

    def __init__(self, cfg: Config, ref: Reference, *, reference_id: str | None = None,
                 block_pulses: int = 1) -> None:
        self.cfg, self.ref = cfg, ref
        self.reference_id = reference_id
        self.pri = cfg.waveform.pri_samples
        self.block_pulses = max(int(block_pulses), 1)
        self._held: list[np.ndarray] = []      # capture periods gathered, not yet analysed
        self._held_at: int | None = None       # stream position of the first one
        self.aligner = new_aligner(cfg, ref)
        self.stream = WarmStart(cfg, ref, by_number=True)
        self._next_sample: int | None = None
        self._pushed = 0                       # samples given to the aligner so far
        self._gaps: list[tuple[int, int]] = []  # (aligner stream position, pulses lost)
        self.lost_pulses = 0
        self.discontinuities = 0

    @property
    def analyzer(self) -> PulseAnalyzer | None:
        """The per-pulse analysis, once the warm-up is done."""
        return self.stream.analyzer

    @property
    def aligned(self) -> bool:
        """True once the direct-coupling edge is found and the warm-up is done."""
        return self.analyzer is not None

    def push(self, samples: np.ndarray, start_sample: int | None = None) -> Estimate | None:
        """Add one capture block; return the current estimate, or None while warming up.

        ``start_sample`` is the block's position in the capture stream (counted by the
        audio thread). A jump means samples were lost (an xrun, a full ring): the pulses in
        the gap are counted as lost and the tracker's clock is advanced by them, so that
        phase rates stay true across the gap. With ``block_pulses`` > 1 the blocks are
        gathered first (a jump analyses what was gathered before it).
        """
        self.feed(samples, start_sample)
        return self.estimate()

    def feed(self, samples: np.ndarray, start_sample: int | None = None) -> None:
        """:meth:`push` without building the estimate (the daemon asks for it once per
        batch of capture periods)."""
        if self.block_pulses > 1:
            if self._held and start_sample is not None and self._held_at is not None \
                    and start_sample != self._held_at + sum(len(h) for h in self._held):
                self.flush()            # a jump: what came before it is analysed alone
            if not self._held:
                self._held_at = start_sample
            self._held.append(np.asarray(samples, dtype=np.float64))
            held = sum(len(h) for h in self._held)
            due = self._due()
            if held >= self.block_pulses * self.pri or \
                    (due is not None and self._pushed + held >= due):
                self.flush()
            return
        self._analyse(samples, start_sample)

    def _due(self) -> int | None:
        """Aligner stream position at which the pulse of the next decision that ends a
        block can be analysed (every ``block_pulses // decide_every``-th decision, on
        pulse numbers: the same ones whatever the latency; None before the first
        decision). Cut on the capture's grid, the deciding pulse waited for the rest of
        its block, a wait set by the latency between the streams modulo the block (0.08
        s through the ALSA loopback, 0.24 s through PipeWire: docs/audio.md)."""
        an = self.analyzer
        nth = self.block_pulses // self.cfg.tracking.decide_every
        k = an.next_decision(nth) if an is not None else None
        if k is None:
            return None
        # the analyzer counts pulses lost in capture gaps; the aligner does not
        return self.aligner.hand_on_at(k - sum(n for _, n in self._gaps))

    def wanted(self) -> int:
        """Capture periods (PRIs) to read before the next analysis: the rest of the
        block, or fewer, up to the one that completes the pulse of the decision that
        ends it (the daemon reads this many: a decision is published after the same
        pulses of its own whatever the latency between the streams)."""
        held = sum(len(h) for h in self._held)
        n = self.block_pulses - held // self.pri
        due = self._due()
        if due is not None:
            n = min(n, -(-(due - self._pushed - held) // self.pri))
        return max(n, 1)

    def flush(self) -> None:
        """Analyse the capture periods gathered so far (``block_pulses`` > 1)."""
        if self._held:
            held, at = self._held, self._held_at
            self._held, self._held_at = [], None
            self._analyse(held[0] if len(held) == 1 else np.concatenate(held), at)

    def _analyse(self, samples: np.ndarray, start_sample: int | None) -> None:
        if start_sample is not None:
            if self._next_sample is not None and start_sample != self._next_sample:
                gap = start_sample - self._next_sample
                self.discontinuities += 1
                lost = max(gap, 0) // self.pri
                self.lost_pulses += lost
                self._gaps.append((self._pushed, lost))
            self._next_sample = start_sample + len(samples)
        got = self.aligner.push(samples)
        self._pushed += len(samples)
        if len(got) and self._gaps:
            self._mend_gaps(got)
        self.stream.push(got)

    def _mend_gaps(self, got: AlignedPulses) -> None:
        """Pulses after a gap get the lost pulses added to their number (the tracker's
        clock); a pulse whose window straddles the gap holds samples of two different
        times and is marked as a drop-out."""
        reach = self.ref.gate.stop + _INTERP_MARGIN
        offset = np.zeros(len(got), dtype=np.int64)
        for pos, lost in self._gaps:
            offset += np.where(got.edges >= pos, lost, 0)
            straddle = (got.edges < pos) & (got.edges + reach > pos) & (got.status == OK)
            got.status[straddle] = DROPOUT
        got.index = got.index + offset
        # a gap is settled once pulses have been emitted beyond it; keep its offset by
        # folding it into a single carried entry
        settled = [(p, n) for p, n in self._gaps if got.edges[-1] > p + reach]
        if settled:
            carried = sum(n for _, n in settled)
            self._gaps = [(0, carried)] + [g for g in self._gaps if g not in settled]

    def estimate(self) -> Estimate | None:
        """The decision over the last ``daemon.window_s`` (None while warming up)."""
        an = self.analyzer
        if an is None or an.state is None:
            return None
        window = round(min(self.cfg.daemon.window_s, an.seen / self.cfg.prf_hz), 3)
        d: Decision = an.state
        if an.state_edge is not None:
            now = self._pushed + sum(len(h) for h in self._held)
            d = predicted(d, (now - an.state_edge) / self.cfg.audio.sample_rate,
                          self.cfg.tracking.rate_floor_hz)
        return Estimate.from_decision(d, window_s=window, reference=self.reference_id)

    def steady_rate_hz(self) -> float | None:
        """The published speed while the fan turns one way at a settled rate, else None
        (what the reference keeper compares with the reference's speed)."""
        an = self.analyzer
        d = an.state if an is not None else None
        if d is None or d.direction not in WAYS or d.rate_state != RateState.SETTLED \
                or d.rate_hz is None:
            return None
        return float(d.rate_hz)

    def fit_sample(self) -> tuple[bool, float] | None:
        """(is the fan moving, mean match quality of the last window) for the reference
        fit watch (reference_fit.py); None while warming up. Moving is the long motion
        meter's verdict or a turning state: a reference that no longer fits gives
        *unknown* while the meter still sees the fan move."""
        an = self.analyzer
        if an is None or an.state is None:
            return None
        moving = bool(an.motion_fed >= self.cfg.tracking.motion_threshold) or \
            an.state.direction in WAYS
        _, quality = an.recent_match()
        return moving, quality

    def take_events(self) -> list[Event]:
        """Motion events (started, stopped, reversed) confirmed since the last call."""
        return self.analyzer.take_events() if self.analyzer is not None else []

    def stats(self) -> dict[str, Any]:
        an = self.analyzer
        drift = (self.aligner.period / self.pri - 1.0) * 1e6 if self.aligner.acquired else math.nan
        return {
            "pulses_aligned": an.seen if an else 0,
            "dropped_pulses": (an.dropped if an else 0) + self.lost_pulses,
            "discontinuities": self.discontinuities,
            "clock_ppm": round(drift, 1) if math.isfinite(drift) else None,
            # what the device shows: clipped coupling share, gain wander (dB), pulses
            # skipped for bursts, the room's tail (PRIs) -- docs/audio.md
            "device": device_figures(self.aligner, an),
        }
