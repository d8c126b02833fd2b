"""The reference's slow work off the processing loop: learning, rewriting, forgetting.

Folding a recording into a reference takes about a second of CPU, writing it an fsync;
the per-pulse loop must keep publishing meanwhile. One worker thread runs these jobs one
at a time; the loop submits them and collects the results on its next pass, so that
everything the daemon's state depends on is still changed by the loop alone.

Every write is atomic (io/reference.py: temporary file, fsync, rename, folder fsync),
and the reference replaced or forgotten is kept as ``<daemon.reference>.previous``.
"""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Config
from ..errors import BladesonarError, EstimationError
from .memory import give_back_memory

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JobResult:
    """What a job gave: ``value`` on success, else ``error`` (a one-line reason)."""

    name: str
    value: Any = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


class ReferenceJobs:
    """One worker thread running submitted jobs in order; results wait for :meth:`poll`."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._todo: collections.deque[tuple[str, Callable[..., Any], tuple[Any, ...]]] = \
            collections.deque()
        self._done: collections.deque[JobResult] = collections.deque()
        self._running: str | None = None
        self._closed = False
        self._thread: threading.Thread | None = None

    @property
    def busy(self) -> str | None:
        """The name of the job queued or running, None when idle."""
        with self._cond:
            if self._running is not None:
                return self._running
            return self._todo[0][0] if self._todo else None

    def submit(self, name: str, fn: Callable[..., Any], *args: Any) -> bool:
        """Queue ``fn(*args)``; False (not queued) while another job is queued or runs."""
        with self._cond:
            if self._closed or self._running is not None or self._todo:
                return False
            self._todo.append((name, fn, args))
            if self._thread is None:
                self._thread = threading.Thread(target=self._work, name="reference-jobs",
                                                daemon=True)
                self._thread.start()
            self._cond.notify()
            return True

    def poll(self) -> list[JobResult]:
        with self._cond:
            got = list(self._done)
            self._done.clear()
            return got

    def wait_idle(self, timeout: float) -> bool:
        """Wait until no job is queued or running (tests, shutdown)."""
        with self._cond:
            return self._cond.wait_for(lambda: self._running is None and not self._todo,
                                       timeout)

    def close(self, timeout: float = 10.0) -> None:
        """Let a running job finish (a write is never cut short), then end the thread."""
        with self._cond:
            self._closed = True
            self._todo.clear()
            self._cond.notify_all()
            t = self._thread
        if t is not None:
            t.join(timeout)
            if t.is_alive():
                log.warning("a reference job was still running at exit")

    def _work(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._todo or self._closed)
                if not self._todo:
                    return
                name, fn, args = self._todo.popleft()
                self._running = name
            try:
                result = JobResult(name, value=fn(*args))
            except BladesonarError as exc:
                result = JobResult(name, error=str(exc) or type(exc).__name__)
            except Exception as exc:  # noqa: BLE001 - a bug must not end the worker
                log.exception("reference job %s failed (a bug: please report it)", name)
                result = JobResult(name, error=f"{type(exc).__name__}: {exc}")
            del fn, args                 # the recording a learn job was given
            give_back_memory()
            with self._cond:
                self._done.append(result)
                self._running = None
                self._cond.notify_all()


# -- the jobs (run in the worker thread; pure apart from the file they write) -------------


def learn(x: np.ndarray, cfg: Config, direction: str, path: Path,
          carried: str = "unknown", estimates: dict[str, int] | None = None,
          why: str = "command") -> dict[str, Any]:
    """Fold ``x`` (a contiguous recording of the fan turning) into a reference, check it,
    keep the old file as ``.previous`` and write the new one atomically; the reference's
    summary (with the airflow measured on ``x``, ``direction_source`` and what decided
    it) and its id out.

    Its direction (airflow_recording.reference_direction): ``direction`` when cw/ccw (a
    person chose it with the select while there was no reference), else ``carried`` when
    cw/ccw (the rotation the estimates against the old reference reported throughout the
    recording, counted in ``estimates``: the direction the user set, or already saw, is
    kept), else the airflow's when confident (nobody set one), else unknown. A confident
    airflow that contradicts a chosen or carried direction is a warning. Raises
    EstimationError when the recording shows no steady rotation or too little of it
    (``reference.min_quality``)."""
    from ..airflow_recording import reference_airflow
    from ..io.reference import keep_previous, write_reference
    from ..reference_build import build_reference, check_compatible

    chosen = reference_airflow(x, cfg, direction if direction in ("cw", "ccw") else None,
                               carried if carried in ("cw", "ccw") else None)
    direction, source = chosen.direction, chosen.source
    ref = build_reference(x, cfg, direction)
    ref.meta["learned_by"] = why      # (what started it: auto, relearn, speed, command)
    if chosen.warnings:
        ref.meta["warnings"] = [*ref.meta.get("warnings", []), *chosen.warnings]
    check_compatible(ref, cfg)
    q = float(ref.meta.get("quality", 0.0))
    if q < cfg.reference.min_quality:
        raise EstimationError(
            f"the recording's table explains only {q:.2f} of its energy (reference."
            f"min_quality {cfg.reference.min_quality:g}): the fan was not turning steadily "
            "(changing speed, stopping) or something else moved; tried again later")
    keep_previous(path)
    digest = write_reference(ref, path)
    out = ref.summary()
    out.update(chosen.keys)
    out["direction_source"] = source
    out["direction_carried"] = carried if carried in ("cw", "ccw") else "unknown"
    out["direction_estimates"] = dict(estimates or {})
    out["id"] = digest[:12]
    return out


def set_direction(path: Path, direction: str) -> str:
    """Store ``direction`` in the reference at ``path`` (rewritten atomically); the new
    file's sha256 out."""
    from ..io.reference import read_reference, write_reference

    ref, _ = read_reference(path)
    ref.meta["direction"] = direction
    return write_reference(ref, path)


def forget(path: Path) -> str | None:
    """Remove the reference (kept as ``.previous``); where it went, as text."""
    from ..io.reference import forget_reference

    prev = forget_reference(path)
    return None if prev is None else str(prev)
