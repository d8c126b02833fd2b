"""A simulated capture fed to the live pipeline one pulse at a time, as the daemon feeds
it (shared by the tests that watch its answers and events pulse by pulse)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from bladesonar.live import LiveAnalyzer, capture_pulses


def pulses(sim: Any, live: LiveAnalyzer, seconds: float
           ) -> Iterator[tuple[int, Any, list[Any]]]:
    """Per pulse: (the capture sample after it, the estimate or None, the events it
    confirmed)."""
    for pos, x in capture_pulses((xs for xs, _ in sim.chunks(seconds)), live.pri):
        est = live.push(x, pos - live.pri)
        yield pos, est, live.take_events()
