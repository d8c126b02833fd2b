"""Opening the audio path a config names (the backends import service/audio.py's types;
this module sits above both, so that no import runs in a circle)."""

from __future__ import annotations

import logging
from typing import Any

from ..errors import AudioDeviceError
from .audio import AudioIO

log = logging.getLogger(__name__)


def choose_backend(cfg: Any) -> str:
    """``cfg.audio.backend``, with ``auto`` resolved from the sound server found: PipeWire
    if one answers, ALSA if none does; a PulseAudio server is refused (docs/audio.md)."""
    backend = str(cfg.audio.backend)
    if backend != "auto":
        return backend
    from . import sound_server
    found = sound_server.detect()
    if found.kind == "pulseaudio":
        raise AudioDeviceError("audio.backend auto: " + sound_server.pulseaudio_refusal(found))
    chosen = "pipewire" if found.kind == "pipewire" else "alsa"
    log.info("sound server: %s; audio path: %s", found.describe(), chosen)
    return chosen


def open_audio(cfg: Any) -> AudioIO:
    """The audio path ``cfg.audio.backend`` names (not started)."""
    backend = choose_backend(cfg)
    if backend == "sim":
        from .sim_audio import SimAudio
        return SimAudio(cfg)
    if backend == "alsa":
        from .alsa_audio import AlsaAudio
        return AlsaAudio(cfg)
    if backend == "pipewire":
        from .pipewire_audio import PipeWireAudio
        return PipeWireAudio(cfg)
    raise AudioDeviceError(f"audio.backend {cfg.audio.backend!r}: use alsa, pipewire, auto "
                           "or sim")
