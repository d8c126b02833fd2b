"""Record an unbroken stretch through the daemon's own audio path (for ``reference --live``).

A reference must be one contiguous recording: a lost period would fold samples of two
different fan angles into one, so any discontinuity aborts with a clear error.
"""

from __future__ import annotations

import logging

import numpy as np

from ..config import Config
from ..errors import AudioDeviceError
from ..progress import Progress

log = logging.getLogger(__name__)


def record(cfg: Config, seconds: float, *, timeout_s: float = 5.0) -> np.ndarray:
    """``seconds`` of capture as float64, from the same audio path ``bladesonar run`` uses."""
    from .backends import open_audio

    pri = cfg.waveform.pri_samples
    n_blocks = int(np.ceil(seconds * cfg.audio.sample_rate / pri))
    audio = open_audio(cfg)
    blocks: list[np.ndarray] = []
    meter = Progress("recording", seconds, " s")
    audio.start()
    try:
        while len(blocks) < n_blocks:
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
            blocks.append(np.asarray(block.samples, dtype=np.float64))
            meter.update(len(blocks) * pri / cfg.audio.sample_rate)
    finally:
        meter.close()
        audio.stop()
    return np.concatenate(blocks)
