"""service/every.py against closed forms: a clock that is a plain number, no sleeping."""

from __future__ import annotations

from bladesonar.service.every import Every


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_due_at_once_then_every_interval_from_when_it_ran() -> None:
    """Polled every 0.25 s with a 1.5 s interval it runs at 0, 1.5, 3.0, ...: k * 1.5
    (all exact in binary). A poll that comes late (at 6.5 for the run due at 6.0) moves
    the next run to 8.0, not 7.5: the loop never runs a job twice in a row to catch up."""
    c = Clock()
    e = Every(1.5, clock=c)
    ran = []
    for k in range(19):             # 0 .. 4.5 s
        c.t = 0.25 * k
        if e.due():
            ran.append(c.t)
    assert ran == [0.0, 1.5, 3.0, 4.5]
    c.t = 5.75
    assert not e.due()
    c.t = 6.5                       # late: the 6.0 run is due now, once
    assert e.due() and not e.due()
    c.t = 7.75
    assert not e.due()
    c.t = 8.0
    assert e.due()


def test_ready_peeks_restart_and_trigger() -> None:
    """``ready`` takes nothing; ``restart`` counts the interval (or a one-off one) from
    now; ``trigger`` makes the job due at once whatever its schedule."""
    c = Clock()
    e = Every(2.0, clock=c)
    assert e.ready() and e.ready()          # peeking does not take it
    e.restart()                              # ran at 0
    c.t = 1.99
    assert not e.ready()
    c.t = 2.0
    assert e.ready(1.0) is False and e.ready() is True   # an explicit now wins
    e.restart(interval=10.0)                 # this time only
    c.t = 11.5
    assert not e.ready()
    c.t = 12.0
    assert e.due()
    c.t = 13.0
    assert not e.ready()
    e.trigger()
    assert e.due() and not e.due()
    c.t = 15.0
    assert e.due()                           # 2.0 after 13.0


def test_callable_interval_is_read_when_the_job_runs() -> None:
    """A reloaded config's interval takes effect from the next run on."""
    c = Clock()
    interval = [1.0]
    e = Every(lambda: interval[0], clock=c)
    assert e.due()                           # next at 1.0
    interval[0] = 5.0
    c.t = 1.0
    assert e.due()                           # next at 6.0
    c.t = 5.5
    assert not e.due()
    c.t = 6.0
    assert e.due()
