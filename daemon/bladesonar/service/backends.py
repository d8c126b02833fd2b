"""Opening the audio path a config names (the backends import service/audio.py's types;
this module sits above both, so that no import runs in a circle)."""

from __future__ import annotations

from typing import Any

from ..errors import AudioDeviceError
from .audio import AudioIO


def open_audio(cfg: Any) -> AudioIO:
    """The audio path ``cfg.audio.backend`` names (not started)."""
    if cfg.audio.backend == "sim":
        from .sim_audio import SimAudio
        return SimAudio(cfg)
    if cfg.audio.backend == "alsa":
        from .alsa_audio import AlsaAudio
        return AlsaAudio(cfg)
    raise AudioDeviceError(f"audio.backend {cfg.audio.backend!r}: use alsa or sim")
