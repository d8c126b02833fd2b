"""The long-running service: audio in, live fingerprinting, messages out, systemd kept told.

One processing loop owns all state; the audio threads and the MQTT client only move bytes.
Faults at the edges (no reference yet, a broker away, an xrun, a bad new config on SIGHUP)
become status, events and counters, never a crash loop.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import os
import signal
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import config as config_mod
from ..answer import Estimate
from ..dsp.stats import median
from ..errors import BladesonarError
from ..io.config_file import load_config
from ..live import LiveAnalyzer
from . import learner, memory, settings_store
from .airflow_watch import AirflowWatch
from .audio import AudioIO, PulseBlock
from .every import Every
from .messages import Command, StatsPayload, utc_iso
from .notify import Notifier, NullNotifier
from .publish import Publisher
from .reference_keeper import REFERENCE_POLL_S, ReferenceKeeper

if TYPE_CHECKING:
    from ..reference_build import Reference

log = logging.getLogger(__name__)

#: Seconds without a captured pulse before the audio path is reopened.
AUDIO_STALL_S = 5.0
#: Wait before reopening the audio path after a capture without a usable pulse train.
SIGNAL_RETRY_S = 10.0
#: How often the reference fit is sampled while tracking, seconds.
FIT_SAMPLE_S = 1.0
#: A reference's direction is taken from the estimates made during its recording when at
#: least this share of them named one rotation and none named the other.
DIRECTION_AGREEMENT = 0.8


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


@dataclasses.dataclass
class Recording:
    """Contiguous capture for a reference being learned live (the loop appends)."""

    why: str
    """``command`` (the Learn button), ``auto`` (no reference yet) or ``relearn`` (stale)."""
    need: int
    """Samples to record."""
    blocks: list[np.ndarray] = dataclasses.field(default_factory=list)
    have: int = 0
    next_sample: int | None = None
    restarts: int = 0
    #: rotations named by the estimates made meanwhile (cw, ccw, other)
    rotations: collections.Counter[str] = dataclasses.field(default_factory=collections.Counter)

    def add(self, block: PulseBlock) -> bool:
        """Append one capture block; a gap (lost samples) starts the recording afresh (a
        reference must be one unbroken stretch). True once complete."""
        if block.discontinuity or (self.next_sample is not None
                                   and block.start_sample != self.next_sample):
            if self.blocks:
                self.restarts += 1
            self.blocks, self.have = [], 0
            self.rotations.clear()
        self.next_sample = block.start_sample + len(block.samples)
        self.blocks.append(np.asarray(block.samples, dtype=np.float64))
        self.have += len(block.samples)
        return self.have >= self.need

    def samples(self) -> np.ndarray:
        return np.concatenate(self.blocks)[:self.need]

    def direction(self, ref_known: bool) -> str:
        """cw or ccw when the running reference knew its direction and the estimates
        during the recording agreed on one; else unknown."""
        if not ref_known:
            return "unknown"
        n = sum(self.rotations.values())
        cw, ccw = self.rotations["cw"], self.rotations["ccw"]
        if n and cw >= DIRECTION_AGREEMENT * n and ccw == 0:
            return "cw"
        if n and ccw >= DIRECTION_AGREEMENT * n and cw == 0:
            return "ccw"
        return "unknown"


class Service:
    """``bladesonar run``: wires config, reference, audio, analysis, publisher and systemd.

    The edges are passed in as factories so the loopback tests run the real ones and a
    phone without systemd simply gets the no-op notifier.
    """

    def __init__(self, cfg: config_mod.Config, *, config_path: str | None,
                 audio_factory: Callable[[config_mod.Config], AudioIO],
                 publisher_factory: Callable[[config_mod.Config], Publisher],
                 analyzer_factory: Callable[[config_mod.Config, Reference], LiveAnalyzer],
                 reference_loader: Callable[[config_mod.Config], Reference],
                 notifier: Notifier | NullNotifier, max_seconds: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        #: the config as the file says; self.cfg adds the settings changed from Home
        #: Assistant (settings_store)
        self._yaml_cfg = cfg
        self._settings_path = settings_store.path_for(cfg)
        cfg, self._stored = settings_store.apply(cfg, settings_store.load(self._settings_path))
        self.cfg = cfg
        self.config_path = config_path
        self.audio_factory = audio_factory
        self.publisher_factory = publisher_factory
        self.notifier = notifier
        self.max_seconds = max_seconds
        self.clock = clock
        self.counters = Counters()
        #: audio counters of device sessions already closed (reopen, reload), so the
        #: published totals never go backwards
        self._audio_closed: dict[str, int] = {}
        self._audio_choice: dict[str, Any] | None = None
        self._stop = threading.Event()
        self._reload = threading.Event()
        #: set by the signal handlers (plain stores, no locks: see install_signal_handlers)
        self._sig_stop = False
        self._sig_reload = False
        self.publisher: Publisher | None = None
        self.audio: AudioIO | None = None
        self._ready_sent = False
        self._last_state: Estimate | None = None
        self._signal_problem_text: str | None = None
        self._cpu_mark = (0.0, 0.0)
        # the loop's clocks (set by _start)
        self._t_start = 0.0
        self._last_pulse_t = 0.0
        self._state_every = Every(lambda: self.cfg.mqtt.publish_interval_s, clock=clock)
        self._stats_every = Every(lambda: self.cfg.mqtt.stats_interval_s, clock=clock)
        self._started_at = utc_iso()
        #: end of the captured period -> its state handed to the publisher, seconds
        self._latencies: list[float] = []
        # the reference managed live (learning, commands, fit)
        self.jobs = learner.ReferenceJobs()
        self._rec: Recording | None = None
        #: cw/ccw of the last estimate that saw the fan turn (None once it stopped)
        self._turning_rotation: str | None = None
        self._learn_why = "command"
        self._job_direction = "unknown"
        self._fit_sample = Every(FIT_SAMPLE_S, clock=clock)
        #: the live airflow (its own worker: a learn job must not hold it up, nor it one)
        self.airflow = AirflowWatch(cfg)
        self.airflow_jobs = learner.ReferenceJobs()
        #: the rotation the fingerprint published when the airflow window was taken
        self._airflow_fp_rotation: str | None = None
        self._status_sent: dict[str, Any] | None = None
        self._status_since = utc_iso()
        #: the reference: load, file watch, fit, learning's back-off, what is published
        self.keeper = ReferenceKeeper(self, reference_loader=reference_loader,
                                      analyzer_factory=analyzer_factory, notifier=notifier,
                                      clock=clock)

    @property
    def analyzer(self) -> LiveAnalyzer | None:
        return self.keeper.analyzer

    @property
    def reference(self) -> Reference | None:
        return self.keeper.reference

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
        """``bladesonar run``'s loop: start, then per wake-up look after what the other
        threads and the files brought, capture a batch, and either learn from it or
        analyse and publish it; shut down whatever way the loop ends."""
        self._start()
        try:
            while not self._stopping():
                now = self.clock()
                if self._time_is_up(now):
                    break
                self._look_after(now)
                if self._idle():
                    continue
                blocks, now = self._capture()
                if not blocks:
                    continue
                self._side_paths(blocks)
                if self.analyzer is None:
                    self._while_learning(blocks, now)
                    continue
                estimate = self._analyse(blocks)
                if estimate is None:
                    continue
                self._took_estimate(estimate, len(blocks), now)
                self._publish(estimate, blocks, now)
        finally:
            self._shut_down()
        return 0

    # -- the loop's phases -----------------------------------------------------------------

    def _start(self) -> None:
        """Publish "starting" and connect before anything slow: Home Assistant must not
        show a previous run's values as current while the reference loads."""
        # before the reference and the warm-up allocate: a fixed mmap threshold keeps the
        # heap from holding what the start freed (service/memory.py)
        memory.fix_mmap_threshold()
        self._t_start = self.clock()
        t = os.times()
        self._cpu_mark = (t.user + t.system, 0.0)   # start-up (imports) is not steady state
        self.publisher = self.publisher_factory(self.cfg)
        # before the connection is even made: no previous run's values shown as current
        # (the publisher sends these retained values before availability online)
        self.publisher.publish_state(Estimate.unknown("starting"), status="starting")
        self.publisher.publish_stats(self.stats(0.0))
        self._publish_status()
        self.publisher.start()
        self.notifier.status("starting")
        self._state_every = Every(lambda: self.cfg.mqtt.publish_interval_s, clock=self.clock)
        self._stats_every = Every(lambda: self.cfg.mqtt.stats_interval_s, clock=self.clock)
        self._last_pulse_t = self._t_start

    def _time_is_up(self, now: float) -> bool:
        """``--seconds``: the tests and benchmarks run the real loop for a set time."""
        if self.max_seconds is not None and now - self._t_start >= self.max_seconds:
            log.info("ran for %.1f s as asked (--seconds); stopping", self.max_seconds)
            return True
        return False

    def _look_after(self, now: float) -> None:
        """Between captures, in this one thread: a reload, the workers' results, the
        commands, the reference file and whether to learn; then the status if it changed.
        Only this thread changes state, so none of it needs a lock."""
        if self._sig_reload or self._reload.is_set():
            self._sig_reload = False     # signals until here join this reload
            self._reload.clear()
            self._do_reload()
        self._take_job_results()
        self._take_airflow()
        self._take_commands()
        if self.keeper.poll(now, busy=bool(self.jobs.busy)):
            self._last_state = None
        self._maybe_learn(now)
        self._publish_status()

    def _idle(self) -> bool:
        """No reference and none to learn: the audio is closed while waiting (nothing
        would read it: xruns) and the loop only looks after its inputs. True if idle."""
        if self.analyzer is None and self._rec is None and not self.keeper.learn_allowed():
            self._close_audio()
            self._pause(min(REFERENCE_POLL_S, 0.25))
            return True
        return False

    def _capture(self) -> tuple[list[PulseBlock], float]:
        """The audio opened if closed, one batch read, and the time after the read. An
        audio path silent for AUDIO_STALL_S is reopened (an unplugged card, a stalled
        sound server): a stall must not end the daemon, nor go unnoticed."""
        if self.audio is None:
            self._open_audio()
            self._last_pulse_t = self.clock()
        assert self.audio is not None
        # analysing: the periods of one analysis block in one wake-up (the loop's own work
        # once a period was a quarter of this thread's CPU), or fewer, up to the one that
        # completes the next decision's pulse (LiveAnalyzer.wanted): read on the capture's
        # grid, a decision waited up to a block, by the latency between the streams
        batch = self.analyzer.wanted() if self.analyzer is not None else 1
        blocks = self.audio.read_pulses(batch, timeout=0.5)
        now = self.clock()
        if not blocks:
            if now - self._last_pulse_t > AUDIO_STALL_S:
                log.warning("no audio for %.1f s; reopening the audio path",
                            now - self._last_pulse_t)
                self.notifier.status("no audio: reopening the device")
                self._close_audio()
                self.counters.audio_restarts += 1
                self._last_pulse_t = now
            return blocks, now
        self._last_pulse_t = now
        return blocks, now

    def _side_paths(self, blocks: list[PulseBlock]) -> None:
        """The capture's other readers, before the analysis (which may pause the loop):
        the airflow window and a reference being recorded."""
        for block in blocks:
            self.airflow.add(block.samples, block.start_sample, block.discontinuity)
        self._maybe_measure_airflow()
        for block in blocks:
            if self._rec is None:        # done (or given up) within the batch
                break
            self._record(block)

    def _while_learning(self, blocks: list[PulseBlock], now: float) -> None:
        """Learning a first reference: pulses flow, nothing to estimate yet; the state
        says so (with the airflow's figures) and the watchdog is kept fed."""
        assert self.publisher is not None
        self.counters.pulses_processed += len(blocks)
        self.notifier.watchdog()
        if self._state_every.due(now):
            self._publish_unknown()
        if self._stats_every.due(now):
            self.publisher.publish_stats(self.stats(now - self._t_start))

    def _analyse(self, blocks: list[PulseBlock]) -> Estimate | None:
        """The batch through the analysis; None while aligning or re-acquiring, or when
        the capture holds no usable pulse train (then a status, and a pause before the
        audio is reopened: retrying at once would only repeat the error)."""
        assert self.analyzer is not None
        try:
            for block in blocks:
                self.analyzer.feed(block.samples, block.start_sample)
                self.counters.pulses_processed += 1
        except BladesonarError as exc:
            # e.g. no direct-coupling pulse: speaker muted, wrong device, unplugged
            self._signal_problem(str(exc))
            self._pause(SIGNAL_RETRY_S)
            return None
        return self.analyzer.estimate()  # None: not aligned yet (or after a gap)

    def _took_estimate(self, estimate: Estimate, n_blocks: int, now: float) -> None:
        """An estimate means the path works: READY once, the watchdog fed, and what the
        learning and the fit watch keep from it (the rotation a recording saw, the
        rotation to carry over a Forget, the fit once a second)."""
        self._signal_problem_text = None
        if not self._ready_sent:
            self._ready_sent = True
            memory.give_back_memory()         # what the start freed
            self.notifier.ready(self._status_line(estimate))
            log.info("running: %s", self._status_line(estimate))
        self.notifier.watchdog()
        if self._rec is not None:
            self._rec.rotations[estimate.rotation or "other"] += n_blocks
        if estimate.rotating is not None:
            self._turning_rotation = estimate.rotation if estimate.rotating else None
        if self._fit_sample.due(now):
            self.keeper.sample_fit(now)

    def _publish(self, estimate: Estimate, blocks: list[PulseBlock], now: float) -> None:
        """The events, then the state on a change or when due (unknown while the
        reference is stale), then the stats when due: an event always comes with the
        state that follows it."""
        assert self.publisher is not None
        stale = self.keeper.stale
        changed = self._events(estimate, publish=not stale)
        if changed or self._state_every.ready(now):
            status, detail = self._status()
            if stale:
                # a reference that no longer fits gives confident wrong answers
                # (measured: a sensor moved by 20 cm): none is published
                estimate = Estimate.unknown(
                    f"the reference no longer fits the room: {detail}",
                    reference=estimate.reference)
            self.publisher.publish_state(self._with_airflow(estimate), status=status,
                                         detail=None if status == "ok" else detail)
            self._publish_status()    # with the state (on change only)
            done_at = blocks[-1].captured_at     # the period that completed it
            if done_at is not None:
                self._latencies.append(self.clock() - done_at)
            self.notifier.status(self._status_line(estimate))
            self._state_every.restart(now)
        if self._stats_every.due(now):
            self.publisher.publish_stats(self.stats(now - self._t_start))
            memory.give_back_memory()     # what the blocks since freed

    def _shut_down(self) -> None:
        """However the loop ended: systemd told, the device and workers closed, and a last
        stats message before the publisher goes (its counters would be lost)."""
        self.notifier.stopping()
        self._close_audio()
        self.jobs.close()
        self.airflow_jobs.close()
        if self.publisher is not None:
            try:
                self.publisher.publish_stats(self.stats(self.clock() - self._t_start))
            finally:
                self.publisher.close()

    # -- pieces --------------------------------------------------------------------------

    def _status_line(self, est: Estimate) -> str:
        rate = est.rate_hz
        rate_s = f"{rate:.3f} Hz" if rate is not None else "rate unknown"
        rot = est.rotation or est.direction.value
        status, _ = self._status()
        tail = f" ({status.replace('_', ' ')})" if status != "ok" else ""
        return f"{rot}, {rate_s}, confidence {est.confidence:.2f}{tail}"

    def _events(self, est: Estimate, publish: bool = True) -> bool:
        """Publish the motion events the analysis confirmed (started, stopped, reversed:
        transitions.py decides them, the same code as ``analyze --track``); True if any,
        or if this is the first estimate. With ``publish`` false (a stale reference) they
        are dropped."""
        assert self.analyzer is not None and self.publisher is not None
        first = self._last_state is None
        self._last_state = est
        fired = first
        for ev in self.analyzer.take_events():
            if publish:
                self.publisher.publish_event(ev.kind, **ev.details())
                fired = True
            else:
                log.debug("event %s not published: the reference is stale", ev.kind)
        return fired

    def _publish_unknown(self) -> None:
        """The state while nothing can be estimated (no reference, no signal). Before a
        reference exists (learning) the airflow window gives what it can: the airflow,
        the rotation it means and the rate from the blade period."""
        assert self.publisher is not None
        status, detail = self._status()
        ref_id = self.reference.meta.get("id") if self.reference is not None else None
        fields = self._with_airflow(Estimate.unknown(detail or status, reference=ref_id))
        f = self.airflow.current()
        if self.reference is None and self._signal_problem_text is None and f is not None \
                and f.rate_hz is not None:
            fields.update(rotating=True, rotation=f.rotation, rate_hz=round(f.rate_hz, 5),
                          rpm=round(60.0 * f.rate_hz, 3),
                          reason=(f"no reference yet: the rate from the blade period, "
                                  f"the rotation from the airflow ({f.airflow.reason})"))
        self.publisher.publish_state(fields, status=status, detail=detail)

    def _with_airflow(self, est: Estimate) -> dict[str, Any]:
        """The estimate's state fields with the live airflow's."""
        out = dict(est.fields())
        out.update(self.airflow.fields())
        return out

    def _maybe_measure_airflow(self) -> None:
        """Submit the airflow window when due (its own worker thread)."""
        learning = self.reference is None
        x = self.airflow.due()
        if x is None or self.airflow_jobs.busy:
            return
        # the blade period's rate too: before a reference (published), and for one the
        # daemon would learn again at another speed (reference_keeper.other_speed_due)
        rate = learning or self.keeper.speed_watched
        from ..airflow_recording import window_figures

        cfg = self.cfg           # as it is now: a reload must not change a job under way

        def job() -> Any:
            return window_figures(x, cfg, rate=rate)

        if self.airflow_jobs.submit("airflow", job):
            self.airflow.submitted(learning)
            st = self._last_state
            self._airflow_fp_rotation = st.rotation if st is not None else None

    def _take_airflow(self) -> None:
        for res in self.airflow_jobs.poll():
            was = self.airflow.contradiction.active
            self.airflow.took(res.value if res.ok else None, res.error,
                              self._airflow_fp_rotation if self.reference is not None
                              else None)
            f = self.airflow.current()
            log.debug("airflow %s", f.airflow if f is not None else res.error)
            if self.keeper.speed_watched:
                self.keeper.note_window_speed(res.value.rate_hz if res.ok else None)
            now = self.airflow.contradiction.active
            if now and not was:
                log.warning("%s", self._status()[1])
            elif was and not now:
                log.info("the live airflow no longer contradicts the reference's direction")

    def _signal_problem(self, problem: str) -> None:
        """The capture holds no usable pulse train: say so once, reopen the audio later."""
        self.counters.signal_errors += 1
        if problem != self._signal_problem_text:
            self._signal_problem_text = problem
            log.error("no usable echo: %s; retrying in %.0f s", problem, SIGNAL_RETRY_S)
            self._publish_unknown()
            self._publish_status()
        self.notifier.status(f"no usable echo: {problem}")
        self._close_audio()
        self._last_state = None

    def _load_reference(self) -> None:
        if self.keeper.load():
            self._last_state = None      # a new analysis: its first estimate is published

    def _open_audio(self) -> None:
        self.keeper.new_analyzer()
        self.audio = self.audio_factory(self.cfg)
        # what was found and chosen (backends.audio_choice), for the status topic; kept
        # while the path is closed
        self._audio_choice = getattr(self.audio, "choice", None) or self._audio_choice
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
        if self._rec is not None:
            self._rec.next_sample = None     # a new stream: the recording starts afresh
            self._rec.blocks, self._rec.have = [], 0

    # -- the reference, managed live -------------------------------------------------------

    def _status(self) -> tuple[str, str | None]:
        """(status, detail) as published: see messages.STATUSES."""
        k = self.keeper
        note = f"{k.learn_note}; " if k.learn_note else ""
        if self._rec is not None or self.jobs.busy == "learn":
            if self._rec is not None:
                return "learning", (f"{note}recording {self.cfg.reference.learn_seconds:g} s "
                                    "of the turning fan for a reference")
            return "learning", f"{note}folding the recording into a reference"
        if k.reference is None:
            if k.problem is None:
                return "starting", None
            if k.learn_allowed():
                if k.learn_failure is not None:
                    return "learning", (f"{note}waiting for a steady rotation to learn a "
                                        f"reference (last try: {k.learn_failure})")
                return "learning", f"{note}waiting to record the turning fan for a reference"
            return ("reference_missing" if k.missing else "reference_invalid", k.problem)
        if self._signal_problem_text is not None:
            return "no_signal", self._signal_problem_text
        if k.fit is not None and k.fit.stale:
            f = k.fit.fit
            return "reference_stale", (
                f"the reference fits the room at {f:.2f} of what it promised over the last "
                f"{k.fit.moving_s:.0f} s of turning (stale below "
                f"{self.cfg.reference.stale_fit:g}): the device, the fan or the room changed; "
                "learn a new reference")
        contra = self.airflow.contradiction_detail(k.reference.meta.get("direction"))
        if contra is not None:
            return "airflow_contradiction", contra
        if self._last_state is None and not self._ready_sent and not k.learned_count:
            return "starting", None
        return "ok", None

    def _publish_status(self) -> None:
        """The status message, when anything in it changed (the fit by 0.03 or more)."""
        if self.publisher is None:
            return
        status, detail = self._status()
        fields: dict[str, Any] = {
            "status": status, "detail": detail,
            **self.keeper.status_fields(),      # reference, its direction and rate, fit
            "learning": (self._rec.why if self._rec is not None else
                         self._learn_why if self.jobs.busy == "learn" else None),
            "settings": settings_store.current(self.cfg),
            "audio": self._audio_choice,
        }
        last = self._status_sent
        if last is not None:
            same = all(last.get(k) == v for k, v in fields.items() if k != "fit")
            f0, f1 = last.get("fit"), fields["fit"]
            fit_same = (f0 is None) == (f1 is None) and (f0 is None or abs(f0 - f1) < 0.03)
            if same and fit_same:
                return
            if last.get("status") != status:
                self._status_since = utc_iso()
        fields["since"] = self._status_since
        self._status_sent = fields
        self.publisher.publish_status(fields)

    def _maybe_learn(self, now: float) -> None:
        """Zero-config: start recording a reference when one is needed and due."""
        if self._rec is not None or self.jobs.busy:
            return
        why = self.keeper.learn_due(now)
        if why is not None:
            self._start_recording(why)

    def _start_recording(self, why: str) -> None:
        need = int(round(self.cfg.reference.learn_seconds * self.cfg.audio.sample_rate))
        self._rec = Recording(why=why, need=need)
        log.info("learning a reference (%s): recording %g s of the fan", why,
                 self.cfg.reference.learn_seconds)
        self._publish_status()

    def _record(self, block: PulseBlock) -> None:
        rec = self._rec
        assert rec is not None
        if rec.why in ("relearn", "speed") and not self.keeper.moving:
            log.info("the fan stopped while recording a reference; trying again later")
            self._rec = None
            self.keeper.retry_later()
            return
        if not rec.add(block):
            return
        ref_known = self.keeper.direction_known()
        # a direction a person chose wins; else what the estimates against the old
        # reference said throughout; else the airflow measured on the recording
        # (learner.learn, airflow_recording.reference_direction)
        direction = self.keeper.pending_direction or "unknown"
        carried = rec.direction(ref_known)
        estimates = {k: int(v) for k, v in sorted(rec.rotations.items())}
        log.info("reference recording complete (%s): direction chosen %s, the estimates "
                 "named %s (old reference's direction %s): carried %s", rec.why, direction,
                 estimates or "nothing", "known" if ref_known else "unknown", carried)
        x = rec.samples()
        self._rec = None
        if not self.jobs.submit("learn", learner.learn, x, self.cfg, direction,
                                self.cfg.reference_path, carried, estimates, rec.why):
            log.warning("a reference job is running; the recording is dropped")
            return
        self._learn_why = rec.why
        self._publish_status()

    def _take_commands(self) -> None:
        assert self.publisher is not None
        for cmd in self.publisher.take_commands():
            self._command(cmd)

    def _command(self, cmd: Command) -> None:
        busy = self.jobs.busy
        if cmd.name == "learn":
            if self._rec is not None or busy:
                log.info("command learn ignored: already %s",
                         "learning" if self._rec is not None or busy == "learn" else busy)
                return
            self._start_recording("command")
        elif cmd.name == "forget":
            if busy:
                log.info("command forget ignored: %s is running", busy)
                return
            self._rec = None
            self.jobs.submit("forget", learner.forget, self.cfg.reference_path)
        elif cmd.name == "setting":
            self._setting(cmd)
        elif cmd.name == "direction":
            d = cmd.value or "unknown"
            if self.reference is None:
                self.keeper.pending_direction = d if d != "unknown" else None
                log.info("reference direction %s kept for the next reference learned", d)
                self._publish_status()
                return
            if busy:
                log.info("command direction ignored: %s is running", busy)
                return
            if self.keeper.direction == d:
                return
            self.jobs.submit("direction", learner.set_direction, self.cfg.reference_path, d)
            self._job_direction = d

    def _take_job_results(self) -> None:
        assert self.publisher is not None
        for res in self.jobs.poll():
            if res.name == "learn":
                if self.keeper.learned(res, self._learn_why):
                    self._load_reference()     # at once: no status lies in between
            elif res.name == "forget":
                if res.ok:
                    self._forgotten(res.value)
                else:
                    log.error("forgetting the reference failed: %s", res.error)
            elif res.name == "direction":
                self.keeper.direction_set(res, self._job_direction)
            self._publish_status()

    def _forgotten(self, kept: str | None) -> None:
        """The reference is gone (keeper.forgotten): learn a new one at once if allowed,
        else wait for the Learn button."""
        self.keeper.forgotten(kept, self._turning_rotation)
        self._last_state = None
        if self.keeper.learn_allowed():
            self._start_recording("auto")

    def _setting(self, cmd: Command) -> None:
        """A setting from Home Assistant: checked like the YAML, used at once, stored."""
        assert cmd.key is not None
        try:
            new, stored = settings_store.change(self.cfg, self._yaml_cfg, self._stored,
                                                cmd.key, cmd.value)
        except BladesonarError as exc:
            log.warning("setting from MQTT refused: %s", exc)
            self._status_sent = None      # republish: Home Assistant shows the value in force
            return
        self.cfg, self._stored = new, stored
        if self.keeper.fit is not None:
            self.keeper.fit.stale_fit = self.cfg.reference.stale_fit
        try:
            settings_store.save(self._settings_path, stored)
        except OSError as exc:
            log.error("the setting reference.%s = %r is used but cannot be stored in %s "
                      "(%s); it will be lost at the next start", cmd.key, cmd.value,
                      self._settings_path, exc.strerror or exc)
        log.info("reference.%s set to %r from MQTT", cmd.key, getattr(self.cfg.reference,
                                                                      cmd.key))

    def _do_reload(self) -> None:
        """SIGHUP: validate the new config first; on any error keep the old one running."""
        self.notifier.reloading()
        self.counters.reloads += 1
        try:
            new = load_config(self.config_path) if self.config_path else self.cfg
        except BladesonarError as exc:
            self.counters.reload_errors += 1
            log.error("reload rejected, keeping the running config: %s", exc)
            self.notifier.ready(f"reload rejected: {exc}")
            return
        self._yaml_cfg = new
        new, self._stored = settings_store.apply(
            new, settings_store.load(settings_store.path_for(new)))
        self._settings_path = settings_store.path_for(new)
        old, self.cfg = self.cfg, new
        if (old.audio, old.waveform, old.scene) != (new.audio, new.waveform, new.scene):
            self.airflow = AirflowWatch(new)     # another pulse train or fan: start afresh
        if (old.audio, old.waveform, old.sim) != (new.audio, new.waveform, new.sim):
            self._close_audio()
        if old.mqtt != new.mqtt or old.device_id != new.device_id:
            assert self.publisher is not None
            self.publisher.close()
            self.publisher = self.publisher_factory(new)
            self._status_sent = None
            self._publish_status()
            self.publisher.start()
        # Only what the analysis depends on restarts it: a reload that changes the broker
        # or nothing at all (a reload storm) keeps tracking, so publishing never pauses.
        same = (old.audio, old.waveform, old.scene, old.analysis, old.tracking, old.daemon,
                old.sim) == (new.audio, new.waveform, new.scene, new.analysis, new.tracking,
                             new.daemon, new.sim)
        if same and self.analyzer is not None \
                and self.keeper.unchanged_on_disk():
            log.info("configuration reloaded from %s; analysis settings and reference "
                     "unchanged: tracking goes on", self.config_path)
            if self._ready_sent:
                self.notifier.ready("configuration reloaded; tracking goes on")
            return
        # The reference is re-read (a new one may have been recorded).
        self.keeper.reread()
        log.info("configuration reloaded from %s", self.config_path)
        if self._ready_sent:
            # the reload is done (systemctl reload returns); re-alignment shows in STATUS
            self.notifier.ready("configuration reloaded; re-aligning")

    def stats(self, uptime_s: float) -> StatsPayload:
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
        fit = self.keeper.fit.fit if self.keeper.fit is not None else None
        return {
            "started_at": self._started_at,
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
            "latency_ms": ({"median": round(1e3 * float(median(np.asarray(lat))), 1),
                            "max": round(1e3 * max(lat), 1), "n": len(lat)} if lat else None),
            "reloads": self.counters.reloads,
            "reload_errors": self.counters.reload_errors,
            "signal_errors": self.counters.signal_errors,
            "references_learned": self.keeper.learned_count,
            "learn_failures": self.keeper.learn_failures,
            "commands": pub.get("commands", 0),
            "commands_refused": pub.get("commands_refused", 0),
            "fit": None if fit is None else round(fit, 3),
            "audio": audio,
        }
