"""A simulated capture fed to the live pipeline one pulse at a time, as the daemon feeds
it (shared by the tests that watch its answers and events pulse by pulse)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from bladesonar.live import LiveAnalyzer


def pulses(sim: Any, live: LiveAnalyzer, seconds: float
           ) -> Iterator[tuple[int, Any, list[Any]]]:
    """Per pulse: (the capture sample after it, the estimate or None, the events it
    confirmed)."""
    pri = live.pri
    pos, buf = 0, np.zeros(0)
    for xs, _ in sim.chunks(seconds):
        buf = np.concatenate([buf, xs])
        n = len(buf) // pri
        for i in range(n):
            est = live.push(buf[i * pri:(i + 1) * pri], pos)
            pos += pri
            yield pos, est, live.take_events()
        buf = buf[n * pri:]
