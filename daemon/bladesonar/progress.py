"""Progress on a terminal for long work (simulation, report sweeps); silent when piped."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """A one-line ``label: 42% (12.3 s of 30 s), 3.1 s left`` meter on stderr, TTY only."""

    def __init__(self, label: str, total: float, unit: str = "", *, stream: TextIO | None = None,
                 enabled: bool | None = None, min_interval_s: float = 0.2) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.label, self.total, self.unit = label, max(float(total), 1e-12), unit
        self.t0 = time.monotonic()
        self._last = 0.0
        self.min_interval_s = min_interval_s

    def update(self, done: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < self.min_interval_s and done < self.total:
            return
        self._last = now
        frac = min(max(done / self.total, 0.0), 1.0)
        el = now - self.t0
        eta = f", {el * (1 - frac) / frac:.0f} s left" if 0 < frac < 1 else ""
        self.stream.write(f"\r{self.label}: {100 * frac:3.0f}% ({done:.4g} of "
                          f"{self.total:.4g}{self.unit}){eta}   ")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()
