"""``Every(interval)``: the loop's periodic jobs (state, stats, fit, reference polls).

One small timer instead of a "next_x = now + interval" pair per job, so each job's
rule reads in one line and is tested once. The clock is injected (a monotonic clock in
the daemon, stream seconds for the airflow window, a plain counter in the tests).
"""

from __future__ import annotations

import time
from collections.abc import Callable

Interval = float | Callable[[], float]


class Every:
    """Due at once, then ``interval`` seconds after each time it was taken.

    The next time is counted from when the job ran, not from when it was due: a loop
    that wakes late does not then run the job twice in a row to catch up. ``interval``
    may be a callable, read when the job runs, so a reloaded config takes effect at the
    next run.
    """

    def __init__(self, interval: Interval, *,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.interval = interval
        self.clock = clock
        self._next = float("-inf")

    def _interval(self) -> float:
        i = self.interval
        return float(i()) if callable(i) else float(i)

    def ready(self, now: float | None = None) -> bool:
        """Whether the job is due (without taking it)."""
        return (self.clock() if now is None else now) >= self._next

    def due(self, now: float | None = None) -> bool:
        """True when the job is due, and then the next time is one interval from now."""
        now = self.clock() if now is None else now
        if now < self._next:
            return False
        self.restart(now)
        return True

    def restart(self, now: float | None = None, interval: float | None = None) -> None:
        """The job ran now (or need not run before one interval from now); ``interval``
        overrides the usual one for this time only."""
        now = self.clock() if now is None else now
        self._next = now + (self._interval() if interval is None else interval)

    def trigger(self) -> None:
        """Make the job due at once (something changed that it should look at)."""
        self._next = float("-inf")
