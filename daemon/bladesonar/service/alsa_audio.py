"""ALSA backend: one playback and one capture PCM (pyalsaaudio), two tiny threads.

The playback thread writes the pulse train addressed by a global sample counter (pulse k
at played sample k * pri_samples), so the pulse schedule is PRF-locked by construction
whatever the write sizes. The capture thread reads whole periods (``audio.period_pulses``
PRIs each: the threads wake once a period) and puts each PRI into a bounded ring. Neither
thread does DSP; pyalsaaudio releases the GIL inside read/write. An xrun (-32 from read
or write) is counted and flags the next delivered block as a discontinuity: capture
starts on the first read and playback on the first write, so their offset holds only
until an xrun, and the consumer must re-measure it from the data.

pyalsaaudio is imported lazily: the analysis tools never need it.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Any

from .. import waveform
from ..errors import AudioDeviceError
from .audio import BlockDecoder, CaptureRing, PulseBlock, RawPeriod, bytes_per_sample, encode

if TYPE_CHECKING:
    from ..config import Config

log = logging.getLogger(__name__)

EPIPE = 32


def _alsaaudio() -> Any:
    try:
        import alsaaudio
    except ImportError as exc:
        raise AudioDeviceError(
            "audio.backend alsa needs pyalsaaudio: pip install 'bladesonar[alsa]' (Debian: "
            "apt install libasound2-dev first), or set audio.backend: sim") from exc
    return alsaaudio


class TxSource:
    """Transmit bytes for played samples [start, start + n), from the global counter.

    Whole aligned PRIs past the first pulse are all identical, so a run of them is that one
    encoded once and repeated; anything else is computed by ``waveform.pulse_train_chunk``.
    """

    def __init__(self, cfg: Config) -> None:
        self.cfg = cfg
        self.pri = int(cfg.waveform.pri_samples)
        self.fmt = cfg.audio.format
        pulse_len = len(waveform.cfg_pulse(cfg))
        #: first aligned period start from which every period is the same
        self._steady_from = -(-pulse_len // self.pri) * self.pri
        self._steady = self._make(self._steady_from, self.pri)
        self._runs: dict[int, bytes] = {}

    def _make(self, start: int, n: int) -> bytes:
        return encode(waveform.pulse_train_chunk(start, n, self.cfg), self.fmt)

    def chunk(self, start: int, n: int) -> bytes:
        if n % self.pri == 0 and start % self.pri == 0 and start >= self._steady_from:
            m = n // self.pri
            if m not in self._runs:
                self._runs[m] = self._steady * m
            return self._runs[m]
        return self._make(start, n)


class AlsaAudio:
    """``audio.backend: alsa``; see the module docstring. Implements ``AudioIO``."""

    #: xruns in a row, with no data between them, after which the device is taken to be
    #: gone (the thread ends, the daemon reopens the path); None: never (a card)
    MAX_XRUNS_IN_A_ROW: int | None = None

    def __init__(self, cfg: Config) -> None:
        self.cfg = cfg
        self.pri = int(cfg.waveform.pri_samples)
        self.fmt = cfg.audio.format
        self.period_bytes = self.pri * bytes_per_sample(self.fmt)   # one PRI
        self.period = self.pri * int(cfg.audio.period_pulses)         # one ALSA period
        self._ring = CaptureRing(cfg.audio.ring_pulses)
        self._decoder = BlockDecoder(self.fmt)
        self._tx = TxSource(cfg)
        self._stop = threading.Event()
        self._flag_next = threading.Event()   # playback xrun: offset changed
        self._threads: list[threading.Thread] = []
        self._play: Any = None
        self._cap: Any = None
        self.failure: str | None = None
        self.xruns_playback = 0
        self.xruns_capture = 0
        self.periods_written = 0
        self.periods_read = 0
        self.samples_written = 0
        #: what was found and chosen (backends.audio_choice; empty when built directly)
        self.choice: dict[str, Any] = {}

    # -- opening -------------------------------------------------------------------------

    def _open(self, alsa: Any, kind: str, device: str) -> Any:
        a = self.cfg.audio
        fmt_code = getattr(alsa, f"PCM_FORMAT_{self.fmt}")
        pcm_type = alsa.PCM_PLAYBACK if kind == "playback" else alsa.PCM_CAPTURE
        try:
            pcm = alsa.PCM(type=pcm_type, mode=alsa.PCM_NORMAL, device=device,
                           rate=a.sample_rate, channels=1, format=fmt_code,
                           periodsize=self.period, periods=a.buffer_periods)
        except alsa.ALSAAudioError as exc:
            key = "playback_device" if kind == "playback" else "capture_device"
            raise AudioDeviceError(
                f"cannot open ALSA {kind} device {device!r}: {exc}; check the name with "
                f"`{'aplay' if kind == 'playback' else 'arecord'} -L`, that no other program "
                f"holds it, and audio.{key}") from exc
        try:
            self._check(pcm.info(), kind, device)
        except AudioDeviceError:
            pcm.close()
            raise
        return pcm

    def _check(self, info: dict[str, Any], kind: str, device: str) -> None:
        """Refuse a device that did not accept exactly what the sonar needs."""
        a = self.cfg.audio
        want = (("rate", a.sample_rate, "audio.sample_rate"),
                ("channels", 1, f"audio.{kind}_device (a mono PCM, e.g. plughw:CARD,0)"),
                ("format_name", self.fmt, "audio.format"),
                ("period_size", self.period, "audio.period_pulses (1: one PRI), "
                 "waveform.pri_samples, or use a plughw: device that accepts any period "
                 "size"))
        bad = [(k, info.get(k), v, fix) for k, v, fix in want if info.get(k) != v]
        if bad:
            what = "; ".join(f"{k} is {got!r}, not {v!r} (change {fix})"
                             for k, got, v, fix in bad)
            raise AudioDeviceError(f"ALSA {kind} device {device!r} refused the settings: {what}")
        log.info("ALSA %s %r: %s Hz, %s, period %s, buffer %s frames", kind, device,
                 info.get("rate"), info.get("format_name"), info.get("period_size"),
                 info.get("buffer_size"))

    def start(self) -> None:
        alsa = _alsaaudio()
        a = self.cfg.audio
        self._play = self._open(alsa, "playback", a.playback_device)
        try:
            self._cap = self._open(alsa, "capture", a.capture_device)
        except AudioDeviceError:
            self._play.close()
            self._play = None
            raise
        self._start_threads()

    def _start_threads(self) -> None:
        self._threads = [threading.Thread(target=self._guard, args=(self._playback_loop,),
                                          name="bladesonar-playback", daemon=True),
                         threading.Thread(target=self._guard, args=(self._capture_loop,),
                                          name="bladesonar-capture", daemon=True)]
        for t in self._threads:
            t.start()

    # -- the two threads (bytes only) ----------------------------------------------------

    def _guard(self, loop: Any) -> None:
        """A device error ends the audio path quietly; the daemon sees no blocks and
        reopens it (a stall), instead of crashing."""
        try:
            loop()
        except Exception as exc:  # noqa: BLE001 - report, never kill the service
            if not self._stop.is_set():
                self.failure = f"{threading.current_thread().name}: {exc}"
                log.error("audio thread stopped: %s", self.failure, exc_info=True)
        finally:
            self._ring.close()

    def _gone(self, in_a_row: int, kind: str) -> None:
        if self.MAX_XRUNS_IN_A_ROW is not None and in_a_row >= self.MAX_XRUNS_IN_A_ROW:
            raise AudioDeviceError(f"{kind}: {in_a_row} xruns in a row with no data between "
                                   "them: the device or the server is gone")

    def _playback_loop(self) -> None:
        pcm, period = self._play, self.period
        in_a_row = 0
        while not self._stop.is_set():
            n = pcm.write(self._tx.chunk(self.samples_written, period))
            if n < 0:
                if n != -EPIPE:
                    raise AudioDeviceError(f"playback write failed with error {n}")
                in_a_row += 1
                self._gone(in_a_row, "playback")
                self.xruns_playback += 1
                self._flag_next.set()
                log.warning("playback underrun (%d so far)", self.xruns_playback)
                continue
            in_a_row = 0
            self.samples_written += n
            self.periods_written = self.samples_written // self.pri   # PRIs, like periods_read

    def _capture_loop(self) -> None:
        pcm, fs, pri = self._cap, float(self.cfg.audio.sample_rate), self.pri
        pending = bytearray()
        start = 0          # capture-stream index of pending[0]
        disc = False
        t_last = time.monotonic()
        in_a_row = 0
        while not self._stop.is_set():
            n, data = pcm.read()
            now = time.monotonic()
            if n < 0:
                if n != -EPIPE:
                    raise AudioDeviceError(f"capture read failed with error {n}")
                in_a_row += 1
                self._gone(in_a_row, "capture")
                self.xruns_capture += 1
                # the stream restarts: what was lost is known only from the clock; keep
                # whole periods and always at least one, so the gap is visible downstream
                lost = max(1, round((now - t_last) * fs / pri))
                start += len(pending) // (self.period_bytes // pri) + lost * pri
                pending.clear()
                disc = True
                log.warning("capture overrun (%d so far)", self.xruns_capture)
                continue
            t_last = now
            in_a_row = 0
            pending += data
            while len(pending) >= self.period_bytes:
                if self._flag_next.is_set():
                    self._flag_next.clear()
                    disc = True
                self._ring.put(RawPeriod(bytes(pending[:self.period_bytes]), start, disc,
                                         now))
                del pending[:self.period_bytes]
                start += pri
                disc = False
                self.periods_read += 1

    # -- consumer side -------------------------------------------------------------------

    def read_pulse(self, timeout: float) -> PulseBlock | None:
        raw = self._ring.get(timeout)
        return None if raw is None else self._decoder(raw)

    def read_pulses(self, n: int, timeout: float) -> list[PulseBlock]:
        return [self._decoder(raw) for raw in self._ring.get_batch(n, timeout)]

    def stats(self) -> dict[str, Any]:
        st: dict[str, Any] = {
            "xruns_playback": self.xruns_playback, "xruns_capture": self.xruns_capture,
            "ring_overflows": self._ring.overflows, "periods_written": self.periods_written,
            "periods_read": self.periods_read, "periods_delivered": self._decoder.delivered,
            "failed": int(self.failure is not None)}
        if self.choice:
            st["sound_server"] = {"server": self.choice.get("server"), "path": "alsa",
                                  "backend": self.choice.get("backend")}
        return st

    def stop(self, timeout: float = 2.0) -> None:
        """Join the threads and close the PCMs. Playback is closed first: with the FIFO
        loopback that ends the room's session, which unblocks a pending capture read."""
        self._stop.set()
        play_t, cap_t = (self._threads + [None, None])[:2]
        for t, attr in ((play_t, "_play"), (cap_t, "_cap")):
            if t is not None:
                t.join(timeout)
                if t.is_alive():
                    log.warning("%s did not stop within %.1f s; leaving its device open",
                                t.name, timeout)
                    continue
            pcm = getattr(self, attr)
            if pcm is not None:
                try:
                    pcm.close()
                except Exception:  # noqa: BLE001
                    log.exception("closing the %s PCM failed", attr.strip("_"))
                setattr(self, attr, None)
        self._ring.close()
