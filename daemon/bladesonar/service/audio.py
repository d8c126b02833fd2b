"""The daemon's audio edge: one interface, three backends (a real ALSA card, PipeWire,
the simulator).

The processing loop asks for the pulse repetition intervals (PRIs) of capture of one
analysis block at a time (``daemon.block_pulses``; one while it only records). Every
PRI's block carries its position in the capture stream and a ``discontinuity`` flag:
after an xrun or a dropped period the offset between playback and capture is no longer
known, so the consumer must re-acquire the direct-coupling edge instead of trusting the
old range offset. The audio threads only move bytes; conversion to float64 happens here,
in the consumer's thread.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np

#: Bytes per sample and full scale of each supported ALSA sample format.
FORMATS: dict[str, tuple[np.dtype[np.signedinteger[Any]], float]] = {
    "S16_LE": (np.dtype("<i2"), 32768.0), "S32_LE": (np.dtype("<i4"), 2147483648.0)}


@dataclass(frozen=True)
class PulseBlock:
    """One PRI of capture."""

    samples: np.ndarray
    """float64, shape (pri_samples,), full scale = 1."""
    start_sample: int
    """Capture-stream index of ``samples[0]``; a jump means samples were lost."""
    discontinuity: bool = False
    """Samples were lost or the playback/capture offset changed before this block
    (xrun, ring overflow, restart): re-acquire the direct-coupling edge."""
    captured_at: float | None = None
    """``time.monotonic()`` when the block's last sample was captured (latency stats)."""


class AudioIO(Protocol):
    """What the daemon needs from an audio path (ALSA, the simulator, a test double)."""

    def start(self) -> None: ...

    def read_pulse(self, timeout: float) -> PulseBlock | None:
        """The next PRI of capture, or None if none arrived within ``timeout`` seconds."""
        ...

    def read_pulses(self, n: int, timeout: float) -> list[PulseBlock]:
        """The next ``n`` PRIs of capture once all have arrived, or those that arrived
        within ``timeout`` seconds (possibly none): the loop wakes once per block of
        pulses it analyses together, not once per PRI."""
        ...

    def stats(self) -> dict[str, Any]:
        """Health counters: xruns_playback, xruns_capture, ring_overflows,
        periods_written, periods_read, periods_delivered (integers, summed across
        reopens); a sound-server backend adds what it found (other values)."""
        ...

    def stop(self, timeout: float = 2.0) -> None: ...


# -- sample formats (pure) -------------------------------------------------------------


def decode(data: bytes, fmt: str) -> np.ndarray:
    """Raw little-endian PCM bytes -> float64, full scale = 1."""
    dtype, scale = FORMATS[fmt]
    return np.frombuffer(data, dtype=dtype).astype(np.float64) / scale


def encode(x: np.ndarray, fmt: str) -> bytes:
    """float64 (full scale = 1) -> raw little-endian PCM bytes, rounded and clipped."""
    dtype, scale = FORMATS[fmt]
    info = np.iinfo(dtype)
    y = np.clip(np.rint(np.asarray(x, dtype=np.float64) * scale), info.min, info.max)
    return y.astype(dtype).tobytes()


def bytes_per_sample(fmt: str) -> int:
    return FORMATS[fmt][0].itemsize


# -- the bounded ring between an audio thread and the consumer -------------------------


class RawPeriod(NamedTuple):
    data: bytes
    start_sample: int
    discontinuity: bool
    captured_at: float | None = None


class CaptureRing:
    """Bounded FIFO of raw capture periods; when full the oldest is dropped and counted.

    Dropping the oldest keeps the newest audio (what the tracker needs); the gap in
    ``start_sample`` and the carried ``discontinuity`` flag tell the consumer.
    """

    def __init__(self, maxlen: int) -> None:
        self._q: collections.deque[RawPeriod] = collections.deque()
        self._maxlen = int(maxlen)
        self._cond = threading.Condition()
        self._want = 1                   # periods the consumer waits for (get_batch)
        self.overflows = 0
        self.closed = False

    def put(self, item: RawPeriod) -> None:
        with self._cond:
            if len(self._q) >= self._maxlen:
                dropped = self._q.popleft()
                self.overflows += 1
                if self._q:
                    head = self._q[0]
                    self._q[0] = head._replace(discontinuity=True)
                else:
                    item = item._replace(discontinuity=True)
                del dropped
            self._q.append(item)
            if len(self._q) >= self._want:
                self._cond.notify()      # a consumer waiting for a batch wakes once

    def get(self, timeout: float) -> RawPeriod | None:
        got = self.get_batch(1, timeout)
        return got[0] if got else None

    def get_batch(self, n: int, timeout: float) -> list[RawPeriod]:
        """Up to ``n`` periods, oldest first: waits until ``n`` are queued, or the ring is
        closed with some left, or ``timeout`` seconds pass, then takes what is there
        (possibly none: a closed, empty ring is waited out like an open one, see
        :meth:`close`)."""
        n = max(1, min(int(n), self._maxlen))
        deadline = time.monotonic() + max(float(timeout), 0.0)
        with self._cond:
            self._want = n
            try:
                while len(self._q) < n and not (self.closed and self._q):
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    self._cond.wait(left)
            finally:
                self._want = 1
            return [self._q.popleft() for _ in range(min(n, len(self._q)))]

    def close(self) -> None:
        """No more periods will come (a waiting consumer still waits out its timeout, so
        a caller polling a dead device does not spin)."""
        with self._cond:
            self.closed = True
            self._cond.notify_all()

    def __len__(self) -> int:
        with self._cond:
            return len(self._q)


class BlockDecoder:
    """Consumer side: raw period -> PulseBlock, flagging any jump in the sample index."""

    def __init__(self, fmt: str) -> None:
        self.fmt = fmt
        self._next: int | None = None
        self.delivered = 0

    def __call__(self, raw: RawPeriod) -> PulseBlock:
        x = decode(raw.data, self.fmt)
        disc = raw.discontinuity or (self._next is not None and raw.start_sample != self._next)
        self._next = raw.start_sample + len(x)
        self.delivered += 1
        return PulseBlock(x, raw.start_sample, bool(disc), raw.captured_at)
