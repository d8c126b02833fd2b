"""The long-running service: audio in, live fingerprinting, messages out, systemd kept told.

One processing loop owns all state; the audio threads and the MQTT client only move bytes.
Faults at the edges (no reference yet, a broker away, an xrun, a bad new config on SIGHUP)
become status, events and counters, never a crash loop.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import signal
import statistics
import threading
import time
from pathlib import Path
from typing import Any, Callable

from .. import config as config_mod
from ..errors import BladesonarError, ReferenceMissingError

log = logging.getLogger(__name__)

#: How often the loop looks for a reference file that is missing or invalid (also on
#: SIGHUP), and stats the one in use to notice it replaced or deleted.
REFERENCE_POLL_S = 2.0
#: Seconds without a captured pulse before the audio path is reopened.
AUDIO_STALL_S = 5.0
#: Wait before reopening the audio path after a capture without a usable pulse train.
SIGNAL_RETRY_S = 10.0


def _add_counts(total: dict[str, Any], more: dict[str, Any]) -> dict[str, Any]:
    """``total`` with the integer counters of ``more`` added (other values taken as
    they are): device sessions' counters summed across reopens."""
    out = dict(total)
    for k, v in more.items():
        out[k] = out.get(k, 0) + v if isinstance(v, int) else v
    return out


@dataclasses.dataclass
class Counters:
    """What the stats message reports; the loop is the only writer."""

    pulses_processed: int = 0
    audio_restarts: int = 0
    reloads: int = 0
    reload_errors: int = 0
    signal_errors: int = 0


class Service:
    """``bladesonar run``: wires config, reference, audio, analysis, publisher and systemd.

    The edges are passed in as factories so the loopback tests run the real ones and a
    phone without systemd simply gets the no-op notifier.
    """

    def __init__(self, cfg: config_mod.Config, *, config_path: str | None,
                 audio_factory: Callable[[config_mod.Config], Any],
                 publisher_factory: Callable[[config_mod.Config], Any],
                 analyzer_factory: Callable[[config_mod.Config, Any], Any],
                 reference_loader: Callable[[config_mod.Config], Any],
                 notifier: Any, max_seconds: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self.config_path = config_path
        self.audio_factory = audio_factory
        self.publisher_factory = publisher_factory
        self.analyzer_factory = analyzer_factory
        self.reference_loader = reference_loader
        self.notifier = notifier
        self.max_seconds = max_seconds
        self.clock = clock
        self.counters = Counters()
        #: audio counters of device sessions already closed (reopen, reload), so the
        #: published totals never go backwards
        self._audio_closed: dict[str, int] = {}
        self._stop = threading.Event()
        self._reload = threading.Event()
        #: set by the signal handlers (plain stores, no locks: see install_signal_handlers)
        self._sig_stop = False
        self._sig_reload = False
        self.publisher: Any = None
        self.audio: Any = None
        self.analyzer: Any = None
        self.reference: Any = None
        self._ready_sent = False
        self._last_state: dict[str, Any] | None = None
        self._reference_problem: str | None = None
        #: stat signature of the reference file when it was last read (None: absent)
        self._reference_sig: tuple | None = None
        self._next_reference_check = 0.0
        self._signal_problem_text: str | None = None
        self._cpu_mark = (0.0, 0.0)
        #: end of the captured period -> its state handed to the publisher, seconds
        self._latencies: list[float] = []

    # -- signals -------------------------------------------------------------------------

    def install_signal_handlers(self) -> None:
        """Handlers that only store a flag the loop reads. They must take no lock: a
        handler runs in the main thread between any two bytecodes, so one that calls
        threading.Event.set() deadlocks if the signal lands while the loop holds that
        Event's lock (clear, wait), and a long handler nests under a flood of signals
        until RecursionError (both seen under a SIGHUP storm)."""

        def on_stop(*_: Any) -> None:
            self._sig_stop = True

        def on_hup(*_: Any) -> None:
            self._sig_reload = True

        signal.signal(signal.SIGTERM, on_stop)
        signal.signal(signal.SIGINT, on_stop)
        signal.signal(signal.SIGHUP, on_hup)

    def request_stop(self) -> None:
        self._stop.set()

    def _stopping(self) -> bool:
        return self._sig_stop or self._stop.is_set()

    def _pause(self, seconds: float) -> None:
        """Wait ``seconds`` unless asked to stop (a signal only sets a flag, so the wait is
        sliced to notice it within 0.1 s)."""
        end = time.monotonic() + seconds
        while not self._stopping():
            left = end - time.monotonic()
            if left <= 0:
                return
            self._stop.wait(min(left, 0.1))

    def request_reload(self) -> None:
        self._reload.set()

    # -- the loop ------------------------------------------------------------------------

    def run(self) -> int:
        t_start = self.clock()
        t = os.times()
        self._cpu_mark = (t.user + t.system, 0.0)   # start-up (imports) is not steady state
        self.publisher = self.publisher_factory(self.cfg)
        self.publisher.start()
        self.notifier.status("starting")
        next_state = next_stats = t_start
        last_pulse_t = t_start
        try:
            while not self._stopping():
                now = self.clock()
                if self.max_seconds is not None and now - t_start >= self.max_seconds:
                    log.info("ran for %.1f s as asked (--seconds); stopping", self.max_seconds)
                    break
                if self._sig_reload or self._reload.is_set():
                    self._sig_reload = False     # signals until here join this reload
                    self._reload.clear()
                    self._do_reload()
                if self.analyzer is not None and now >= self._next_reference_check:
                    self._next_reference_check = now + REFERENCE_POLL_S
                    if self._reference_signature() != self._reference_sig:
                        log.info("the reference file changed; reading it again")
                        self.analyzer = None
                if self.analyzer is None and not self._load_reference():
                    self._pause(REFERENCE_POLL_S)
                    continue
                if self.audio is None:
                    self._open_audio()
                    last_pulse_t = self.clock()
                block = self.audio.read_pulse(timeout=0.5)
                now = self.clock()
                if block is None:
                    if now - last_pulse_t > AUDIO_STALL_S:
                        log.warning("no audio for %.1f s; reopening the audio path",
                                    now - last_pulse_t)
                        self.notifier.status("no audio: reopening the device")
                        self._close_audio()
                        self.counters.audio_restarts += 1
                        last_pulse_t = now
                    continue
                last_pulse_t = now
                try:
                    estimate = self.analyzer.push(block.samples, block.start_sample)
                except BladesonarError as exc:
                    # e.g. no direct-coupling pulse: speaker muted, wrong device, unplugged
                    self._signal_problem(str(exc))
                    self._pause(SIGNAL_RETRY_S)
                    continue
                self.counters.pulses_processed += 1
                if estimate is None:  # not aligned yet (or re-acquiring after a gap)
                    continue
                self._signal_problem_text = None
                if not self._ready_sent:
                    self._ready_sent = True
                    self.notifier.ready(self._status_line(estimate))
                    log.info("running: %s", self._status_line(estimate))
                self.notifier.watchdog()
                changed = self._events(estimate)
                if changed or now >= next_state:
                    self.publisher.publish_state({**estimate, "status": "ok"})
                    if block.captured_at is not None:
                        self._latencies.append(self.clock() - block.captured_at)
                    self.notifier.status(self._status_line(estimate))
                    next_state = now + self.cfg.mqtt.publish_interval_s
                if now >= next_stats:
                    self.publisher.publish_stats(self.stats(now - t_start))
                    next_stats = now + self.cfg.mqtt.stats_interval_s
        finally:
            self.notifier.stopping()
            self._close_audio()
            if self.publisher is not None:
                try:
                    self.publisher.publish_stats(self.stats(self.clock() - t_start))
                finally:
                    self.publisher.close()
        return 0

    # -- pieces --------------------------------------------------------------------------

    def _status_line(self, est: dict[str, Any]) -> str:
        rate = est.get("rate_hz")
        rate_s = f"{rate:.3f} Hz" if isinstance(rate, (int, float)) else "rate unknown"
        rot = est.get("rotation") or est.get("direction")
        return f"{rot}, {rate_s}, confidence {est.get('confidence', 0):.2f}"

    def _events(self, est: dict[str, Any]) -> bool:
        """Publish the motion events the analysis confirmed (started, stopped, reversed:
        transitions.py decides them, the same code as ``analyze --track``); True if any,
        or if this is the first estimate."""
        first = self._last_state is None
        self._last_state = est
        fired = first
        for ev in self.analyzer.take_events():
            self.publisher.publish_event(ev.kind, **ev.details())
            fired = True
        return fired

    def _signal_problem(self, problem: str) -> None:
        """The capture holds no usable pulse train: say so once, reopen the audio later."""
        self.counters.signal_errors += 1
        if problem != self._signal_problem_text:
            self._signal_problem_text = problem
            log.error("no usable echo: %s; retrying in %.0f s", problem, SIGNAL_RETRY_S)
            self.publisher.publish_state({"direction": "unknown", "rotation": None,
                                          "rate_hz": None, "rpm": None,
                                          "relative_rate": None, "confidence": 0.0,
                                          "rotating": None,
                                          "reference": self.reference.meta.get("id"),
                                          "status": "no_signal", "detail": problem})
        self.notifier.status(f"no usable echo: {problem}")
        self._close_audio()
        self._last_state = None

    def _reference_signature(self) -> tuple | None:
        """(device, inode, size, mtime) of the reference file, None if absent: a cheap
        stat that tells a replaced or deleted reference from the one in use."""
        try:
            st = os.stat(self.cfg.reference_path)
        except OSError:
            return None
        return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)

    def _load_reference(self) -> bool:
        """Load and check the reference; a missing or invalid one is a published status
        (never an exit: under systemd that would be a restart loop) and is retried when
        the file changes or on SIGHUP."""
        sig = self._reference_signature()
        if self._reference_problem is not None and sig == self._reference_sig:
            return False    # same file as the failed attempt: nothing new to read
        self._reference_sig = sig
        try:
            ref = self.reference_loader(self.cfg)
            analyzer = self.analyzer_factory(self.cfg, ref)
        except Exception as exc:  # noqa: BLE001 - a bad reference must not stop the daemon
            missing = isinstance(exc, ReferenceMissingError)
            if not isinstance(exc, BladesonarError):
                log.exception("the reference could not be used (a bug: please report it)")
            problem = str(exc) or type(exc).__name__
            if problem != self._reference_problem:
                self._reference_problem = problem
                log.error("%s", problem)
                self.notifier.status(f"waiting for a reference: {problem}" if missing
                                     else f"reference invalid: {problem}")
                status = "reference_missing" if missing else "reference_invalid"
                self.publisher.publish_event(status, detail=problem)
                self.publisher.publish_state({"direction": "unknown", "rotation": None,
                                              "rate_hz": None, "rpm": None,
                                              "relative_rate": None, "confidence": 0.0,
                                              "rotating": None, "reference": None,
                                              "status": status,
                                              **({} if missing else {"detail": problem})})
            self.reference = None
            self._close_audio()     # nothing reads it while we wait: no xruns piling up
            return False
        self._reference_problem = None
        self.reference = ref
        self.analyzer = analyzer
        log.info("reference loaded: %s (%.3f Hz, %s)", ref.meta.get("id"),
                 ref.meta.get("rate_hz", float("nan")), ref.meta.get("direction"))
        return True

    def _open_audio(self) -> None:
        # a new capture stream is a new time base: align and warm up from scratch
        self.analyzer = self.analyzer_factory(self.cfg, self.reference)
        self.audio = self.audio_factory(self.cfg)
        self.audio.start()

    def _close_audio(self) -> None:
        if self.audio is not None:
            try:
                self._audio_closed = _add_counts(self._audio_closed, self.audio.stats())
            except Exception:  # noqa: BLE001 - counters must not block the close
                log.exception("reading the audio counters failed")
            try:
                self.audio.stop()
            except Exception:  # noqa: BLE001 - closing must not mask the real error
                log.exception("closing the audio path failed")
            self.audio = None

    def _do_reload(self) -> None:
        """SIGHUP: validate the new config first; on any error keep the old one running."""
        self.notifier.reloading()
        self.counters.reloads += 1
        try:
            new = config_mod.load(self.config_path) if self.config_path else self.cfg
        except BladesonarError as exc:
            self.counters.reload_errors += 1
            log.error("reload rejected, keeping the running config: %s", exc)
            self.notifier.ready(f"reload rejected: {exc}")
            return
        old, self.cfg = self.cfg, new
        if (old.audio, old.waveform, old.sim) != (new.audio, new.waveform, new.sim):
            self._close_audio()
        if old.mqtt != new.mqtt or old.device_id != new.device_id:
            self.publisher.close()
            self.publisher = self.publisher_factory(new)
            self.publisher.start()
        # Only what the analysis depends on restarts it: a reload that changes the broker
        # or nothing at all (a reload storm) keeps tracking, so publishing never pauses.
        same = (old.audio, old.waveform, old.scene, old.analysis, old.tracking, old.daemon,
                old.sim) == (new.audio, new.waveform, new.scene, new.analysis, new.tracking,
                             new.daemon, new.sim)
        if same and self.analyzer is not None \
                and self._reference_signature() == self._reference_sig:
            log.info("configuration reloaded from %s; analysis settings and reference "
                     "unchanged: tracking goes on", self.config_path)
            if self._ready_sent:
                self.notifier.ready("configuration reloaded; tracking goes on")
            return
        # The reference is re-read (a new one may have been recorded).
        self.analyzer = None
        self._reference_problem = None
        log.info("configuration reloaded from %s", self.config_path)
        if self._ready_sent:
            # the reload is done (systemctl reload returns); re-alignment shows in STATUS
            self.notifier.ready("configuration reloaded; re-aligning")

    def stats(self, uptime_s: float) -> dict[str, Any]:
        """The stats message: health counters a user can alert on, plus the raw detail."""
        audio = dict(self._audio_closed)
        if self.audio is not None:
            audio = _add_counts(audio, self.audio.stats())
        pub = dict(self.publisher.counters()) if self.publisher is not None else {}
        an = dict(self.analyzer.stats()) if self.analyzer is not None else {}
        t = os.times()
        cpu = t.user + t.system
        prev_cpu, prev_up = self._cpu_mark
        self._cpu_mark = (cpu, uptime_s)
        span = uptime_s - prev_up
        lat, self._latencies = self._latencies, []
        return {
            "uptime_s": round(uptime_s, 1),
            "cpu_share": round((cpu - prev_cpu) / span, 4) if span > 0 else None,
            "pulses_processed": self.counters.pulses_processed,
            "dropped_pulses": an.get("dropped_pulses", 0),
            "xruns": int(audio.get("xruns_capture", 0)) + int(audio.get("xruns_playback", 0)),
            "reconnects": pub.get("reconnects", 0),
            "dropped_events": pub.get("dropped_events", 0),
            "clock_ppm": an.get("clock_ppm"),
            "device": an.get("device"),      # clipped coupling, gain wander, bursts, tail
            "audio_restarts": self.counters.audio_restarts,
            "latency_ms": ({"median": round(1e3 * statistics.median(lat), 1),
                            "max": round(1e3 * max(lat), 1), "n": len(lat)} if lat else None),
            "reloads": self.counters.reloads,
            "reload_errors": self.counters.reload_errors,
            "signal_errors": self.counters.signal_errors,
            "audio": audio,
        }
