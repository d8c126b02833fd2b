"""The loopback room: the device's self-test through its real ALSA code path.

The daemon plays into ALSA PCM ``bladesonar_play`` (file plugin on ``fifo_play``) and
captures from ``bladesonar_cap`` (infile on ``fifo_cap``). The room reads exactly what was
played, one PRI block at a time, convolves each block with the scene's echo response at
the fan angle of that block's time (the schedule), overlap-adds, and writes the result as
the capture stream, optionally paced at the sample rate. Capture sample
``latency + n`` holds the room's answer to played sample ``n``.

Rules found by testing (docs/audio.md): the room opens fifo_play read-only and fifo_cap
read-write before the daemon opens its PCMs (the daemon's open would block, holding the
GIL); at least one ALSA buffer of silence is in fifo_cap before the daemon's first read;
every write is whole capture periods and goes in only when the pipe has room for all of
it (a reader that sees half a period corrupts it).
"""

from __future__ import annotations

import array
import fcntl
import json
import logging
import math
import os
import select
import stat
import termios
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np
from scipy.signal import fftconvolve

from ..errors import AudioDeviceError, ConfigError
from ..service.audio import bytes_per_sample, decode, encode

if TYPE_CHECKING:
    from ..config import Config
    from ..sim.scene import Scene

log = logging.getLogger(__name__)

F_SETPIPE_SZ = getattr(fcntl, "F_SETPIPE_SZ", 1031)
F_GETPIPE_SZ = getattr(fcntl, "F_GETPIPE_SZ", 1032)
#: Capture latency beyond one ALSA buffer, so the coupling edge is not on a period boundary.
EXTRA_LATENCY = 321
#: How often blocking waits look at the stop flag.
POLL_S = 0.1


@dataclass
class RoomStats:
    periods_played: int = 0
    periods_captured: int = 0
    seconds: float = 0.0
    ended_by: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


def make_fifo(path: Path) -> None:
    """Create a FIFO, or accept an existing one; refuse anything else at that path."""
    if path.exists():
        if not stat.S_ISFIFO(path.stat().st_mode):
            raise AudioDeviceError(f"{path} exists and is not a FIFO; remove it or choose "
                                   "another --dir")
        return
    os.mkfifo(path, 0o600)


class Room:
    """One loopback session (see the module docstring).

    Parameters
    ----------
    scene, cfg : the scene and the daemon's config (sample rate, PRI, format, buffer).
    schedule : rotation schedule (string or Schedule); None: the scene's, else
        ``cfg.sim.schedule``.
    fifo_play, fifo_cap : the FIFOs the ALSA config names (created if missing).
    realtime : pace the capture stream at the sample rate (else as fast as possible).
    latency_samples : capture delay of the room's answer; None: one ALSA buffer + 321.
    noise_sigma : white Gaussian noise added to the capture (full scale = 1).
    truth : file to write one JSON line per played PRI block (fan angle etc.).
    ir_samples : length of the echo response (echoes later than one PRI fold into the
        next pulse, as in a real room); None: two PRIs.
    """

    def __init__(self, scene: Scene, cfg: Config, schedule: Any = None, *, fifo_play: Path | str,
                 fifo_cap: Path | str, realtime: bool = False,
                 latency_samples: int | None = None, noise_sigma: float = 0.0, seed: int = 0,
                 truth: IO[str] | None = None, ir_samples: int | None = None) -> None:
        from ..sim import schedule as _schedule

        self.scene = scene.with_config(cfg)
        self.cfg = cfg
        if schedule is None:
            schedule = scene.schedule if scene.schedule is not None else cfg.sim.schedule
        self.schedule = _schedule.parse(schedule, key="schedule")
        self.fifo_play, self.fifo_cap = Path(fifo_play), Path(fifo_cap)
        self.realtime = bool(realtime)
        self.pri = int(cfg.waveform.pri_samples)
        self.fs = float(cfg.audio.sample_rate)
        self.fmt = cfg.audio.format
        self.period_bytes = self.pri * bytes_per_sample(self.fmt)
        #: what the room writes at once: one ALSA period of the daemon's capture (the
        #: infile plugin's reader must never see part of one)
        self.unit = int(cfg.audio.period_pulses) * self.pri
        buffer = cfg.audio.buffer_periods * self.unit
        if latency_samples is None:
            latency_samples = buffer + EXTRA_LATENCY
        if latency_samples < buffer:
            raise ConfigError("latency_samples", latency_samples, "must be at least one ALSA "
                              "buffer (audio.buffer_periods x period_pulses x pri_samples = "
                              f"{buffer}): the capture needs that much silence before the "
                              "first echo")
        self.latency = int(latency_samples)
        #: capture position of the answer to pulse 0 (the PipeWire room's: per session):
        #: the noise is a function of the position from there (``_noise``)
        self._noise_origin = self.latency
        self.noise_sigma = float(noise_sigma)
        self.seed = int(seed)
        self.truth = truth
        self.ir_samples = int(ir_samples) if ir_samples else 2 * self.pri
        self._fd_play: int | None = None
        self._fd_cap: int | None = None
        self._acc = np.zeros(0)        # capture samples not yet written, from _acc_start
        self._acc_start = 0
        self._t0: float | None = None    # when the daemon's first played samples arrived
        self.stats = RoomStats()

    # -- set-up --------------------------------------------------------------------------

    def open(self) -> None:
        """Create and open both FIFO ends and pre-write the silence: call before the
        daemon opens its PCMs."""
        try:
            make_fifo(self.fifo_play)
            make_fifo(self.fifo_cap)
            self._fd_play = os.open(self.fifo_play, os.O_RDONLY | os.O_NONBLOCK)
            self._fd_cap = os.open(self.fifo_cap, os.O_RDWR)
        except OSError as exc:
            self.close()
            raise AudioDeviceError(f"cannot create or open the loopback FIFOs: {exc}") from exc
        # small play pipe: the daemon's playback cannot run far ahead of a paced room;
        # large capture pipe: room for the pre-written silence and a few periods
        self._set_pipe_size(self._fd_play, 4096)
        self._cap_size = self._set_pipe_size(self._fd_cap, 1 << 20)
        if self._cap_size < 2 * (self.latency + 2 * self.unit) * bytes_per_sample(self.fmt):
            log.warning("capture pipe holds only %d bytes", self._cap_size)
        self._drain(self._fd_cap)           # stale samples of an earlier session
        # the capture stream starts with whole periods of silence: the latency before the
        # room's first answer, of which the part past a period boundary stays in _acc
        self._acc_start = 0
        self._acc = np.zeros(self.latency)
        self._emit(upto=(self.latency // self.unit) * self.unit, pace=False)

    @staticmethod
    def _set_pipe_size(fd: int, size: int) -> int:
        try:
            fcntl.fcntl(fd, F_SETPIPE_SZ, size)
        except OSError as exc:
            log.debug("F_SETPIPE_SZ %d: %s", size, exc)
        return int(fcntl.fcntl(fd, F_GETPIPE_SZ))

    @staticmethod
    def _drain(fd: int) -> None:
        flags = fcntl.fcntl(fd, fcntl.F_GETFL)
        fcntl.fcntl(fd, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        try:
            while os.read(fd, 1 << 16):
                pass
        except BlockingIOError:
            pass
        finally:
            fcntl.fcntl(fd, fcntl.F_SETFL, flags)

    def close(self) -> None:
        for name in ("_fd_play", "_fd_cap"):
            fd = getattr(self, name)
            if fd is not None:
                os.close(fd)
                setattr(self, name, None)

    def __enter__(self) -> Room:
        self.open()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- the session ---------------------------------------------------------------------

    def serve(self, *, connect_timeout: float | None = None, max_seconds: float | None = None,
              should_stop: Callable[[], bool] = lambda: False) -> RoomStats:
        """Answer played blocks until the daemon closes its playback PCM (or a limit)."""
        assert self._fd_play is not None, "open() first"
        poller = select.poll()
        poller.register(self._fd_play, select.POLLIN)
        buf = bytearray()
        k = 0
        t_open = time.monotonic()
        self._t0 = None
        while True:
            if should_stop():
                self.stats.ended_by = "stopped"
                break
            now = time.monotonic()
            if self._t0 is None and connect_timeout is not None and now - t_open > connect_timeout:
                self.stats.ended_by = "no daemon"
                break
            if self._t0 is not None and max_seconds is not None and now - self._t0 > max_seconds:
                self.stats.ended_by = "time limit"
                break
            if not poller.poll(int(POLL_S * 1000)):
                continue
            try:
                data = os.read(self._fd_play, self.period_bytes - len(buf))
            except BlockingIOError:
                continue
            if not data:
                self.stats.ended_by = "daemon closed"
                break
            if self._t0 is None:
                self._t0 = time.monotonic()
                log.info("daemon connected: answering its pulses")
                # paced, the pre-written silence is read at once, and the period holding
                # the answer to played sample n goes out when its last sample is due
                self._truth_session(((self.latency % self.unit) + self.unit) / self.fs
                                    if self.realtime else 0.0)
            buf += data
            if len(buf) < self.period_bytes:
                continue
            self._answer(k, decode(bytes(buf), self.fmt))
            buf.clear()
            k += 1
            if not self._emit(upto=self.latency + k * self.pri, pace=self.realtime,
                              should_stop=should_stop):
                self.stats.ended_by = "stopped"
                break
        self.stats.periods_played = k
        self.stats.seconds = time.monotonic() - (self._t0 or t_open)
        return self.stats

    def _noise(self, start: int, n: int) -> np.ndarray:
        """The capture's white noise at positions [start, start + n), drawn per PRI
        counted from the answer to the session's pulse 0 (``_noise_origin``): pulse k of
        every session gets the same noise in every room (FIFO or PipeWire, whatever the
        latency and the write sizes), so two paths can be compared on the same data
        (the reversal's detection delay moves by 0.7 s between noise draws)."""
        pri, origin = self.pri, self._noise_origin
        first, last = (start - origin) // pri, (start + n - 1 - origin) // pri
        draws = [np.random.default_rng([self.seed, 0x100, (1 << 40) + b]).standard_normal(pri)
                 for b in range(first, last + 1)]
        a = start - origin - first * pri
        return self.noise_sigma * np.concatenate(draws)[a:a + n]

    def _truth_session(self, answer_delay_s: float) -> None:
        """A truth line for a session's start: when its pulse 0 reached the room (wall
        clock), and how much later the room's answer to a block enters the capture."""
        if self.truth is not None:
            self.truth.write(json.dumps({"session_started_at": time.time(),
                                         "answer_delay_s": answer_delay_s}) + "\n")
            self.truth.flush()

    def _answer(self, k: int, played: np.ndarray, at_sample: int | None = None) -> None:
        """Echoes of played block k (fan static during the block), overlap-added at
        capture sample ``at_sample`` (default: latency + k * pri)."""
        from ..sim.render import echo_response

        t = k * self.pri / self.fs
        angle = float(self.schedule.angle_at(np.array([t]), self.scene.start_angle_rad)[0])
        h = echo_response(self.scene, self.cfg, angle, self.ir_samples)
        y = fftconvolve(played, h) if np.any(played) else np.zeros(len(played) + len(h) - 1)
        at = (self.latency + k * self.pri if at_sample is None else at_sample) \
            - self._acc_start
        need = at + len(y)
        if need > len(self._acc):
            self._acc = np.concatenate([self._acc, np.zeros(need - len(self._acc))])
        self._acc[at:at + len(y)] += y
        if self.truth is not None:
            K = self.scene.K
            rate = float(self.schedule.rate_at(np.array([t]))[0])
            self.truth.write(json.dumps(dict(
                pulse=k, played_sample=k * self.pri, capture_sample=self.latency + k * self.pri,
                time_s=t, angle_rad=angle, phase=float(np.mod(angle * K / (2 * math.pi), 1.0)),
                rate_hz=rate)) + "\n")

    def _emit(self, upto: int, pace: bool,
              should_stop: Callable[[], bool] = lambda: False) -> bool:
        """Write every whole capture period (``unit``) that ends at or before capture
        sample ``upto``."""
        assert self._fd_cap is not None
        u = self.unit
        while self._acc_start + u <= upto:
            x = self._acc[:u]
            if self.noise_sigma > 0:
                x = x + self._noise(self._acc_start, u)
            data = encode(x, self.fmt)
            if pace and self._t0 is not None:
                # period j is complete when its last sample has been "recorded"
                j = self._acc_start // u - self.latency // u
                wait = self._t0 + (j + 1) * u / self.fs - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
            if not self._wait_room(len(data), should_stop):
                return False
            n = os.write(self._fd_cap, data)
            if n != len(data):   # cannot happen on a blocking pipe with room; be loud
                raise AudioDeviceError(f"short write to {self.fifo_cap}: {n} of {len(data)}")
            self._acc = self._acc[u:]
            self._acc_start += u
            self.stats.periods_captured += 1
        return True

    def _wait_room(self, n: int, should_stop: Callable[[], bool]) -> bool:
        """Wait until fifo_cap can take n bytes in one piece (the reader then never sees a
        partial period)."""
        assert self._fd_cap is not None
        buf = array.array("i", [0])
        while True:
            fcntl.ioctl(self._fd_cap, termios.FIONREAD, buf, True)
            if buf[0] + n <= self._cap_size:
                return True
            if should_stop():
                return False
            time.sleep(0.001)
