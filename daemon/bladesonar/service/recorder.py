"""Record an unbroken stretch through the daemon's own audio path (for ``reference --live``).

A reference must be one contiguous recording: a lost period would fold samples of two
different fan angles into one, so any discontinuity aborts with a clear error.

The recording starts at the first pulse heard, not at the capture's start: the capture
runs a latency (the ALSA buffer, a sound server's graph) before the first pulse comes
back, and counted from the capture's start the same ``--seconds`` held 324 pulses through
the ALSA loopback and 331 through PipeWire, two references for one fan and room (and
answers 0.35 s apart on one schedule: docs/audio.md).
"""

from __future__ import annotations

import logging

import numpy as np

from ..config import Config
from ..dsp.pulses import coupling_peak
from ..errors import AudioDeviceError
from ..progress import Progress

log = logging.getLogger(__name__)


#: Capture periods (PRIs) of lead-in skipped at most before recording anyway (the
#: aligner's own bound, PulseAligner.max_lead_in: 1.9 s at 44.1 kHz)
LEAD_IN_PRIS = 64
def holds_pulse(x: np.ndarray) -> bool:
    """Whether one PRI of capture holds the direct coupling of a pulse
    (:func:`dsp.pulses.coupling_peak`)."""
    a = np.abs(np.nan_to_num(np.asarray(x, dtype=np.float64)))
    return bool(len(a)) and coupling_peak(a) is not None


def record(cfg: Config, seconds: float, *, timeout_s: float = 5.0) -> np.ndarray:
    """``seconds`` of capture as float64, from the same audio path ``bladesonar run`` uses,
    starting half a PRI before the first pulse's direct coupling (the lead-in before it
    skipped, at most LEAD_IN_PRIS), so that every path records the same pulses."""
    from .backends import open_audio

    pri = cfg.waveform.pri_samples
    n_blocks = int(np.ceil(seconds * cfg.audio.sample_rate / pri))
    audio = open_audio(cfg)
    blocks: list[np.ndarray] = []
    lead: np.ndarray | None = None       # the last PRI of lead-in
    skipped = 0
    meter = Progress("recording", seconds, " s")
    audio.start()
    try:
        # one PRI more than asked: the cut below starts up to a PRI into the first
        while len(blocks) < n_blocks + 1:
            block = audio.read_pulse(timeout=timeout_s)
            if block is None:
                raise AudioDeviceError(f"no audio arrived for {timeout_s:g} s from "
                                       f"{cfg.audio.capture_device!r} (backend "
                                       f"{cfg.audio.backend}); check the device and that no "
                                       "other program holds it (systemctl stop bladesonar)")
            if block.discontinuity and blocks:
                raise AudioDeviceError(
                    f"capture lost samples after {len(blocks) * pri / cfg.audio.sample_rate:.1f}"
                    " s (xrun or overflow); a reference needs one unbroken recording: try "
                    "again, or raise audio.buffer_periods")
            x = np.asarray(block.samples, dtype=np.float64)
            if not blocks and skipped < LEAD_IN_PRIS and not holds_pulse(x):
                lead = None if block.discontinuity else x
                skipped += 1
                continue
            blocks.append(x)
            meter.update(min(len(blocks), n_blocks) * pri / cfg.audio.sample_rate)
    finally:
        meter.close()
        audio.stop()
    if skipped:
        log.info("recording from the first pulse heard, %d PRIs (%.2f s) into the capture",
                 skipped, skipped * pri / cfg.audio.sample_rate)
    x = np.concatenate(([lead] if lead is not None else []) + blocks)
    # the first peak half a PRI into the recording, whatever the latency
    at = (pri if lead is not None else 0) + int(np.argmax(np.abs(np.nan_to_num(blocks[0]))))
    cut = max(at - pri // 2, 0)
    return x[cut:cut + n_blocks * pri]
