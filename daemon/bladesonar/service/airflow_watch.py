"""The daemon's live airflow: a rolling window of the capture, measured now and then off
the loop, and the rule that turns a sustained contradiction into a status (pure: no
threads or I/O here; the runner submits the measurement to a worker thread).

Why a window of raw capture and not the fingerprint's aligned pulses: those exist only
once a reference does and are gated for the fingerprint, while the airflow is wanted
before the first reference (and its stage measures on its own gate, as ``analyze`` does,
so the daemon gives the figures docs/airflow.md reports). Aligning a window again costs
about 15 ms.

Times are stream seconds (samples captured / sample rate), so a paced and an unpaced
run (the tests' simulator) decide alike; paced, they are wall seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..airflow_recording import WindowFigures
from .every import Every

if TYPE_CHECKING:
    from ..config import Config

#: Seconds of capture each measurement reads. The stage needs 8 blocks of 16 usable
#: pulse pairs (about 4 s) to call at all; the held-out sweep's recordings were 6-15 s
#: (docs/airflow.md), and 12 s sits inside what was measured while keeping the window's
#: memory at 2 MiB (float32).
WINDOW_S = 12.0
#: Stream seconds between measurements while a reference runs: one costs about 0.12 s of
#: CPU on a 12 s window, and a fan's airflow changes only when someone reverses it. Every
#: 30 s cost 0.50 % of a core in tools/bench_daemon (the worker thread's share), every
#: 60 s 0.31 % (docs/mqtt.md#the-live-airflow).
EVERY_S = 60.0
#: Between measurements before the first reference: the rate from the blade period is
#: then the only rate there is (0.33 s of CPU with it), and no fingerprint runs.
EVERY_LEARNING_S = 10.0
#: A measurement older than this (stream seconds) is no longer published.
KEEP_S = 3 * EVERY_S + WINDOW_S
#: A contradiction becomes a status once every measurement for this long contradicted
#: the fingerprint's direction (4 windows in a row at EVERY_S): a reversal the
#: fingerprint saw before the airflow window did, or one odd window, never is one.
SUSTAIN_S = 3 * EVERY_S
#: It clears at the first confident agreement, or after this long without a
#: contradiction (measurements that cannot compare: unknown airflow or rotation).
CLEAR_S = 3 * EVERY_S


class SampleWindow:
    """The last ``n`` samples of an unbroken capture (float32 ring); a gap or a
    discontinuity starts it afresh."""

    def __init__(self, n: int) -> None:
        if n < 1:
            raise ValueError(f"window of {n} samples: give at least 1")
        self._buf = np.zeros(n, dtype=np.float32)
        self._have = 0
        self._pos = 0
        self._next: int | None = None

    @property
    def full(self) -> bool:
        return self._have >= len(self._buf)

    def reset(self) -> None:
        self._have, self._pos, self._next = 0, 0, None

    def add(self, samples: np.ndarray, start_sample: int | None,
            discontinuity: bool = False) -> None:
        if discontinuity or (self._next is not None and start_sample is not None
                             and start_sample != self._next):
            self.reset()
        x = np.asarray(samples, dtype=np.float32)
        n = len(self._buf)
        if len(x) >= n:
            self._buf[:] = x[-n:]
            self._pos, self._have = 0, n
        else:
            end = self._pos + len(x)
            if end <= n:
                self._buf[self._pos:end] = x
            else:
                k = n - self._pos
                self._buf[self._pos:] = x[:k]
                self._buf[:end - n] = x[k:]
            self._pos = end % n
            self._have = min(n, self._have + len(x))
        self._next = None if start_sample is None else start_sample + len(x)

    def samples(self) -> np.ndarray:
        """The window in time order, float64 (a copy)."""
        if not self.full:
            return self._buf[:self._have].astype(np.float64)
        return np.concatenate([self._buf[self._pos:], self._buf[:self._pos]]).astype(
            np.float64)


@dataclass
class Contradiction:
    """A live airflow that confidently contradicts the fingerprint's direction, for long
    enough to be a status (:data:`SUSTAIN_S`), until it stops (:data:`CLEAR_S`)."""

    sustain_s: float = SUSTAIN_S
    clear_s: float = CLEAR_S
    since: float | None = None
    """Stream time of the first contradiction of the current run."""
    last: float | None = None
    """Stream time of the latest contradiction."""
    active: bool = False
    figures: dict[str, Any] | None = None

    def update(self, t: float, contradicts: bool | None,
               figures: dict[str, Any] | None = None) -> bool:
        """One measurement at stream time ``t``: True (the airflow's rotation and the
        fingerprint's differ, both known), False (they agree), None (no comparison). The
        status afterwards."""
        if contradicts is True:
            if self.since is None:
                self.since = t
            self.last = t
            self.figures = figures
            if t - self.since >= self.sustain_s:
                self.active = True
        elif contradicts is False:
            self.since = self.last = None
            self.active = False
        else:
            if not self.active:
                self.since = None       # the run is broken: it starts again
            elif self.last is not None and t - self.last >= self.clear_s:
                self.since = self.last = None
                self.active = False
        return self.active

    def duration_s(self) -> float:
        if self.since is None or self.last is None:
            return 0.0
        return self.last - self.since


class AirflowWatch:
    """The window, when to measure it, the latest figures and the contradiction."""

    def __init__(self, cfg: Config) -> None:
        self.fs = float(cfg.audio.sample_rate)
        self.downdraft_rotation = cfg.scene.downdraft_rotation
        self.window = SampleWindow(int(round(WINDOW_S * self.fs)))
        self.samples_seen = 0
        self._every = Every(EVERY_S, clock=lambda: self.now)
        self.latest: WindowFigures | None = None
        self.latest_at: float | None = None
        self.error: str | None = None
        self.contradiction = Contradiction()
        self.measurements = 0

    @property
    def now(self) -> float:
        """Stream seconds captured so far."""
        return self.samples_seen / self.fs

    def add(self, samples: np.ndarray, start_sample: int | None,
            discontinuity: bool = False) -> None:
        self.window.add(samples, start_sample, discontinuity)
        self.samples_seen += len(samples)

    def due(self) -> np.ndarray | None:
        """The window's samples when a measurement is due (the window full and
        EVERY_S, or EVERY_LEARNING_S before a reference, since the last), else None.
        Call :meth:`submitted` once the job is queued."""
        if not self.window.full or not self._every.ready():
            return None
        return self.window.samples()

    def submitted(self, learning: bool) -> None:
        self._every.restart(interval=EVERY_LEARNING_S if learning else EVERY_S)

    def took(self, figures: WindowFigures | None, error: str | None,
             fingerprint_rotation: str | None) -> None:
        """A measurement's result (or why it failed), compared with the rotation the
        fingerprint published when it was taken (None: unknown, stopped, no
        reference)."""
        t = self.now
        self.measurements += 1
        self.latest, self.latest_at, self.error = figures, t, error
        turn = figures.rotation if figures is not None else None
        contra = None if turn is None or fingerprint_rotation not in ("cw", "ccw") \
            else turn != fingerprint_rotation
        figs = None
        if contra and figures is not None:
            a = figures.airflow
            figs = {"airflow": a.airflow, "airflow_confidence": round(a.confidence, 3),
                    "airflow_t": round(a.t, 1), "airflow_rotation": turn,
                    "fingerprint_rotation": fingerprint_rotation}
        self.contradiction.update(t, contra, figs)

    def current(self) -> WindowFigures | None:
        """The latest figures while fresh (:data:`KEEP_S`)."""
        if self.latest is None or self.latest_at is None \
                or self.now - self.latest_at > KEEP_S:
            return None
        return self.latest

    def fields(self) -> dict[str, Any]:
        """The state's airflow keys: ``airflow`` (down/up/unknown) and its confidence
        (null before a measurement)."""
        f = self.current()
        if f is None:
            return {"airflow": "unknown", "airflow_confidence": None}
        c = f.airflow.confidence
        return {"airflow": f.airflow.airflow,
                "airflow_confidence": round(c, 4) if math.isfinite(c) else None}

    def contradiction_detail(self, reference_direction: str | None) -> str | None:
        """The status detail while a contradiction is a status, with its figures."""
        c = self.contradiction
        if not c.active or c.figures is None:
            return None
        f = c.figures
        return (f"the airflow measured from the echoes is {f['airflow']} (confidence "
                f"{f['airflow_confidence']:.2f}, t {f['airflow_t']:+.1f}), which with "
                f"scene.downdraft_rotation {self.downdraft_rotation} means "
                f"{f['airflow_rotation']}, but the fingerprint says "
                f"{f['fingerprint_rotation']} (reference direction {reference_direction}), "
                f"for {c.duration_s():.0f} s: the reference's direction is probably set "
                f"the wrong way; set it to {f['airflow_rotation']} (or check "
                "scene.downdraft_rotation)")
