"""The reference's life in the daemon: load, watch the file, judge the fit, learn, retire.

The service loop asks this one object whether there is a reference, an analyzer built on
it, whether it went stale and whether one should be learned now; everything the daemon
publishes about the reference (its events, its part of the status message) is said here.
The live recording and the worker thread stay in the loop (they carry the audio).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol, TypedDict

from ..answer import EventKind
from ..config import Config
from ..errors import BladesonarError, ReferenceMissingError
from ..live import LiveAnalyzer
from ..reference_build import SPEED_ADVICE
from ..reference_fit import FitWatch
from .airflow_watch import AirflowWatch, Contradiction
from .every import Every
from .learner import JobResult
from .notify import Notifier, NullNotifier
from .publish import Publisher

if TYPE_CHECKING:
    from ..reference_build import Reference

log = logging.getLogger(__name__)

#: How often the loop looks for a reference file that is missing or invalid (also on
#: SIGHUP), and stats the one in use to notice it replaced or deleted.
REFERENCE_POLL_S = 2.0
#: A reference the daemon learned by itself at a speed its table holds poorly (warned:
#: ``reference_build.SPEED_ADVICE``) is learned again once the fan has turned steadily at
#: least this share faster or slower for ``OTHER_SPEED_S`` (the warning asks for a few
#: per cent; the gap warning's room was right 24 % of its day, and 94 % at 4 %).
OTHER_SPEED_SHARE = 0.03
OTHER_SPEED_S = 10.0


class ReferenceStatus(TypedDict):
    """The reference's keys in the status message (docs/mqtt.md)."""

    reference: str | None
    reference_direction: str | None
    reference_rate_hz: float | None
    fit: float | None


class Host(Protocol):
    """What the keeper reads from the service: the config, publisher and airflow watch in
    force (a reload replaces them) and the status the service composes."""

    @property
    def cfg(self) -> Config: ...

    @property
    def publisher(self) -> Publisher | None: ...

    @property
    def airflow(self) -> AirflowWatch: ...

    def _status(self) -> tuple[str, str | None]: ...

    def _publish_status(self) -> None: ...

    def _publish_unknown(self) -> None: ...


class ReferenceKeeper:
    """The reference in use (or why there is none), its analyzer and its fit watch."""

    def __init__(self, host: Host, *,
                 reference_loader: Callable[[Config], Reference],
                 analyzer_factory: Callable[[Config, Reference], LiveAnalyzer],
                 notifier: Notifier | NullNotifier,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.host = host
        self.reference_loader = reference_loader
        self.analyzer_factory = analyzer_factory
        self.notifier = notifier
        self.clock = clock
        self.reference: Reference | None = None
        self.analyzer: LiveAnalyzer | None = None
        self.fit: FitWatch | None = None
        #: why there is no usable reference (None: none tried yet, or one in use)
        self.problem: str | None = None
        self.missing = False
        #: stat signature of the reference file when it was last read (None: absent)
        self._sig: tuple[int, int, int, int] | None = None
        #: stat the reference in use / try to load a missing or invalid one
        self._check = Every(REFERENCE_POLL_S, clock=clock)
        self._try = Every(REFERENCE_POLL_S, clock=clock)
        #: the motion meter's verdict at the last fit sample (the fan moves)
        self.moving = False
        self._stale_reported = False
        #: a direction chosen while there was no reference, or the rotation the fan had
        #: when its reference was forgotten: given to the next one learned
        self.pending_direction: str | None = None
        # learning: when to try again, the back-off, the last failure, a note for the status
        self.learn_next_try = 0.0
        self.learn_wait = host.cfg.reference.retry_s
        self.learn_failure: str | None = None
        self.learn_note: str | None = None
        self.learned_count = 0
        self.learn_failures = 0
        #: since when the fan has turned steadily at another speed than a reference
        #: learned at a poor one (``other_speed_due``); None: not now
        self._other_since: float | None = None
        #: the latest blade-period window (reference-free) found another speed
        self._other_window = False
        #: no relearn at another speed before this time (one per reference.retry_max_s:
        #: a window that misread the speed must not make a learning loop)
        self._speed_after = 0.0

    # -- the file ------------------------------------------------------------------------

    def signature(self) -> tuple[int, int, int, int] | None:
        """(device, inode, size, mtime) of the reference file, None if absent: a cheap
        stat that tells a replaced or deleted reference from the one in use."""
        try:
            st = os.stat(self.host.cfg.reference_path)
        except OSError:
            return None
        return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)

    def unchanged_on_disk(self) -> bool:
        return self.signature() == self._sig

    def poll(self, now: float, busy: bool) -> bool:
        """Every REFERENCE_POLL_S: re-read a reference file replaced or deleted under the
        running analysis, try again one missing or invalid. Not while a job may be writing
        the file. True when a reference was (re)loaded."""
        if self.analyzer is not None and not busy and self._check.due(now):
            if not self.unchanged_on_disk():
                log.info("the reference file changed; reading it again")
                self.analyzer = None
                self._try.trigger()
        if self.analyzer is None and not busy and self._try.due(now):
            return self.load()
        return False

    def reread(self) -> None:
        """A new config (SIGHUP): read the reference again at once, learn again if due."""
        self.analyzer = None
        self.problem = None
        self._try.trigger()
        self.learn_next_try = 0.0

    def load(self) -> bool:
        """Load and check the reference; a missing or invalid one is a published status
        (never an exit: under systemd that would be a restart loop) and is retried when
        the file changes or on SIGHUP."""
        host = self.host
        assert host.publisher is not None
        sig = self.signature()
        if self.problem is not None and sig == self._sig:
            return False    # same file as the failed attempt: nothing new to read
        self._sig = sig
        try:
            ref = self.reference_loader(host.cfg)
            analyzer = self.analyzer_factory(host.cfg, ref)
        except Exception as exc:  # noqa: BLE001 - a bad reference must not stop the daemon
            missing = isinstance(exc, ReferenceMissingError)
            if not isinstance(exc, BladesonarError):
                log.exception("the reference could not be used (a bug: please report it)")
            problem = str(exc) or type(exc).__name__
            self.reference = None
            self.analyzer = None
            self.fit = None
            if problem != self.problem:
                self.problem = problem
                self.missing = missing
                if self.learn_allowed():
                    # the daemon learns one itself: no advice to make one by hand
                    problem = problem.split("; make one")[0]
                    self.problem = problem
                    log.info("%s; learning one from the turning fan (reference.%s)",
                             problem, "auto_learn" if missing else "auto_relearn")
                    self.notifier.status("learning a reference from the turning fan")
                else:
                    log.error("%s", problem)
                    self.notifier.status(f"waiting for a reference: {problem}" if missing
                                         else f"reference invalid: {problem}")
                status = "reference_missing" if missing else "reference_invalid"
                host.publisher.publish_event(EventKind(status), detail=problem)
                host._publish_status()
                host._publish_unknown()
            return False
        self.problem = None
        self.missing = False
        self.reference = ref
        self.analyzer = analyzer
        q = float(ref.meta.get("quality") or 0.0)
        r = host.cfg.reference
        self.fit = FitWatch(q, stale_fit=r.stale_fit, span_s=r.stale_after_s) if q > 0 \
            else None
        self._stale_reported = False
        self._other_since, self._other_window = None, False
        host.airflow.contradiction = Contradiction()     # judged against this one afresh
        if self.pending_direction is not None \
                and ref.meta.get("direction") == self.pending_direction:
            self.pending_direction = None
        log.info("reference loaded: %s (%.3f Hz, %s)", ref.meta.get("id"),
                 ref.meta.get("rate_hz", float("nan")), ref.meta.get("direction"))
        return True

    def new_analyzer(self) -> None:
        """A new capture stream is a new time base: align and warm up from scratch."""
        if self.reference is not None:
            self.analyzer = self.analyzer_factory(self.host.cfg, self.reference)

    # -- what it says ----------------------------------------------------------------------

    @property
    def direction(self) -> str | None:
        return self.reference.meta.get("direction") if self.reference is not None else None

    def direction_known(self) -> bool:
        return self.direction in ("cw", "ccw")

    @property
    def stale(self) -> bool:
        return self.fit is not None and self.fit.stale

    def status_fields(self) -> ReferenceStatus:
        """The reference's part of the status message."""
        ref = self.reference
        fit = self.fit.fit if self.fit is not None else None
        return {
            "reference": ref.meta.get("id") if ref is not None else None,
            "reference_direction": (ref.meta.get("direction") if ref is not None
                                    else self.pending_direction),
            "reference_rate_hz": ref.meta.get("rate_hz") if ref is not None else None,
            "fit": None if fit is None else round(fit, 2),
        }

    # -- the fit ---------------------------------------------------------------------------

    def sample_fit(self, now: float) -> None:
        """The reference fit watch, once a second; a stale reference is an event once."""
        if self.fit is None or self.analyzer is None:
            return
        got = self.analyzer.fit_sample()
        if got is None:
            return
        moving, quality = got
        self.moving = moving
        self._note_speed(now, self.analyzer.steady_rate_hz())
        was = self.fit.stale
        self.fit.update(now, moving, quality)
        if self.fit.stale and not was and not self._stale_reported:
            self._stale_reported = True
            _, detail = self.host._status()
            log.warning("%s", detail)
            assert self.host.publisher is not None
            self.host.publisher.publish_event(EventKind.REFERENCE_STALE, detail=detail,
                                              fit=round(self.fit.fit or 0.0, 3))
        elif was and not self.fit.stale:
            self._stale_reported = False
            log.info("the reference fits the room again (fit %.2f)", self.fit.fit or 0.0)

    # -- learning, replacing, retiring -----------------------------------------------------

    def learn_allowed(self) -> bool:
        """Whether the daemon learns by itself now (no reference, or a bad one)."""
        r = self.host.cfg.reference
        if self.reference is None:
            if self.problem is None:
                return False
            return r.auto_learn if self.missing else r.auto_relearn
        return r.auto_relearn and self.fit is not None and self.fit.stale

    def _other_speed(self, rate_hz: float | None) -> bool:
        """Whether ``rate_hz`` is ``OTHER_SPEED_SHARE`` or more off the reference's."""
        ref_hz = self.reference.meta.get("rate_hz") if self.reference is not None else None
        return isinstance(ref_hz, (int, float)) and ref_hz > 0 and rate_hz is not None \
            and abs(abs(rate_hz) / ref_hz - 1.0) >= OTHER_SPEED_SHARE

    def _note_speed(self, now: float, rate_hz: float | None) -> None:
        """Follow how long the fan has turned steadily at another speed than the
        reference's (``rate_hz``: the published speed while it is settled, else None)."""
        if not self._other_speed(rate_hz):
            self._other_since = None
        elif self._other_since is None:
            self._other_since = now

    @property
    def speed_watched(self) -> bool:
        """Whether the reference is one the daemon would learn again at another speed
        (``other_speed_due``): the airflow window then measures the blade period too."""
        ref = self.reference
        return ref is not None and self.host.cfg.reference.auto_learn \
            and ref.meta.get("learned_by") in ("auto", "relearn", "speed") \
            and any(SPEED_ADVICE in str(w) for w in ref.meta.get("warnings") or [])

    def note_window_speed(self, rate_hz: float | None) -> None:
        """A reference-free measurement of the speed from the blade period over the
        airflow's window (12 s of a steady period, or none): a poor reference's own
        answers may be unknown or unsettled at another speed."""
        self._other_window = self._other_speed(rate_hz)

    def other_speed_due(self, now: float) -> bool:
        """Whether to learn again a reference the daemon learned by itself at a speed its
        table holds poorly (its warnings ask for another fan speed: a period of nearly a
        whole number of pulses), now that the fan has turned steadily at another speed
        for ``OTHER_SPEED_S`` of settled answers, or over the latest blade-period window
        (``note_window_speed``). Nobody reads the warning on a zero-config device; a person
        who made or asked for the reference has read it, and it is left alone."""
        if not self.speed_watched or not self.moving or now < self._speed_after:
            return False
        return self._other_window or (self._other_since is not None
                                      and now - self._other_since >= OTHER_SPEED_S)

    def learn_due(self, now: float) -> str | None:
        """Zero-config: why to start recording a reference now (auto, relearn, speed), or
        None."""
        if now < self.learn_next_try:
            return None
        if not self.learn_allowed():
            if not self.other_speed_due(now):
                return None
            self.learn_note = ("the reference was learned at a fan speed whose blade angles "
                               "its table holds poorly; learning it again at this speed")
            return "speed"
        if self.reference is not None and not self.moving:
            # re-learning a stale reference: only from a fan seen moving now (the motion
            # meter: the stale reference's own answers may well be unknown)
            return None
        if self.reference is not None:
            f = self.fit.fit if self.fit is not None else None
            self.learn_note = ("the reference no longer fits the room"
                               + (f" (fit {f:.2f})" if f is not None else ""))
        return "auto" if self.reference is None else "relearn"

    def retry_later(self) -> None:
        """A recording given up (the fan stopped): the next try after the back-off."""
        self.learn_next_try = self.clock() + self.learn_wait

    def learned(self, res: JobResult, why: str) -> bool:
        """A learn job's result, published; True when a new reference was written (the
        caller loads it at once, so that no status lies between)."""
        publisher = self.host.publisher
        assert publisher is not None
        cfg = self.host.cfg
        if res.ok:
            info = res.value
            self.learned_count += 1
            self.learn_failure = None
            self.learn_note = None
            self.learn_wait = cfg.reference.retry_s
            if why == "speed":
                self._speed_after = self.clock() + cfg.reference.retry_max_s
            log.info("reference learned (%s): %s, %.3f Hz, quality %.2f, direction %s (%s; "
                     "carried %s, airflow %s, confidence %s, t %s: %s)", why,
                     info.get("id"), info.get("rate_hz", float("nan")),
                     info.get("quality", float("nan")), info.get("direction"),
                     info.get("direction_source"), info.get("direction_carried"),
                     info.get("airflow"), info.get("airflow_confidence"),
                     info.get("airflow_t"), info.get("airflow_reason"))
            # what the reference advises (another place, another speed) reaches a
            # headless user through the journal as well as the event
            for w in info.get("warnings") or []:
                log.warning("reference %s: %s", info.get("id"), w)
            # what decided the direction, for whoever wonders why it is what it is
            publisher.publish_event(
                EventKind.REFERENCE_LEARNED, reference=info.get("id"), rate_hz=info.get("rate_hz"),
                quality=info.get("quality"), direction=info.get("direction"), source=why,
                direction_source=info.get("direction_source"),
                direction_carried=info.get("direction_carried"),
                direction_estimates=info.get("direction_estimates"),
                airflow=info.get("airflow"), airflow_confidence=info.get("airflow_confidence"),
                airflow_t=info.get("airflow_t"), airflow_reason=info.get("airflow_reason"),
                warnings=info.get("warnings") or [])
            # read back what was written, new analyzer, re-align
            self.analyzer = None
            self.problem = None
            self._try.restart()
            return True
        self.learn_failures += 1
        self.learn_failure = res.error
        log.warning("learning a reference failed (%s): %s; next automatic try in %.0f s",
                    why, res.error, self.learn_wait)
        publisher.publish_event(EventKind.REFERENCE_LEARN_FAILED, detail=res.error, source=why)
        self.learn_next_try = self.clock() + self.learn_wait
        self.learn_wait = min(2.0 * self.learn_wait, cfg.reference.retry_max_s)
        return False

    def direction_set(self, res: JobResult, direction: str) -> None:
        """A direction job's result: the file was rewritten with ``direction``."""
        publisher = self.host.publisher
        assert publisher is not None
        if res.ok and self.reference is not None:
            # the table is unchanged: the running analysis takes the direction at once
            # (its reference is this object), no re-alignment
            self.reference.meta["direction"] = direction
            self.reference.meta["id"] = str(res.value)[:12]
            self.host.airflow.contradiction = Contradiction()
            if self.analyzer is not None:
                self.analyzer.reference_id = self.reference.meta["id"]
            self._sig = self.signature()
            log.info("reference direction set to %s (reference %s)", direction,
                     self.reference.meta["id"])
            publisher.publish_event(EventKind.REFERENCE_DIRECTION_SET, direction=direction,
                                    reference=self.reference.meta["id"])
        elif not res.ok:
            log.error("setting the reference direction failed: %s", res.error)
            publisher.publish_event(EventKind.REFERENCE_LEARN_FAILED, detail=res.error)

    def forgotten(self, kept: str | None, turning_rotation: str | None) -> None:
        """The reference is gone: one step to learning a new one (or to waiting for the
        Learn button). The rotation the fan had is carried to the new reference, so the
        direction chosen for the old one is not lost (unless the fan was not seen
        turning with a known direction)."""
        assert self.host.publisher is not None
        old = self.direction
        log.info("reference forgotten%s", f" (kept as {kept})" if kept else "")
        self.host.publisher.publish_event(EventKind.REFERENCE_FORGOTTEN, detail=kept)
        if self.pending_direction is None and old in ("cw", "ccw") \
                and turning_rotation in ("cw", "ccw"):
            self.pending_direction = turning_rotation
        self.analyzer = None
        self.reference = None
        self.fit = None
        # the file is gone and that is known: no reference_missing event follows
        self.problem = ("the reference was forgotten; learn a new one with the "
                        "Learn reference button or the learn command")
        self.missing = True
        self._sig = self.signature()
        self.learn_failure = None
        self.learn_next_try = 0.0
        self.learn_wait = self.host.cfg.reference.retry_s
        self.learn_note = "the reference was forgotten"
