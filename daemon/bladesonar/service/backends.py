"""Opening the audio path a config names (the backends import service/audio.py's types;
this module sits above both, so that no import runs in a circle)."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from ..errors import AudioDeviceError
from .audio import AudioIO

if TYPE_CHECKING:
    from ..config import Config
    from .alsa_audio import AlsaAudio
    from .pipewire_audio import PipeWireAudio
    from .sim_audio import SimAudio

log = logging.getLogger(__name__)


#: The audio path each backend takes, as ``stats`` and the status topic name it.
PATHS = {"alsa": "alsa", "pipewire": "pipewire-alsa", "sim": "sim"}


def audio_choice(cfg: Config) -> dict[str, Any]:
    """What was found and chosen: ``backend`` (the config's ``audio.backend``),
    ``server`` (the sound server that answers: ``pipewire``, ``pulseaudio``, ``none``;
    null for the simulator, which looks for none) and ``chosen`` (the backend used:
    ``auto`` resolved to PipeWire if one answers, ALSA if none does; a PulseAudio server
    is refused, docs/audio.md) with its ``path``."""
    backend = str(cfg.audio.backend)
    if backend == "sim":
        return {"backend": backend, "server": None, "chosen": "sim", "path": PATHS["sim"]}
    from . import sound_server
    found = sound_server.detect()
    chosen = backend
    if backend == "auto":
        if found.kind == "pulseaudio":
            raise AudioDeviceError("audio.backend auto: "
                                   + sound_server.pulseaudio_refusal(found))
        chosen = "pipewire" if found.kind == "pipewire" else "alsa"
    log.info("sound server: %s; audio.backend %s: audio path %s", found.describe(), backend,
             PATHS.get(chosen, chosen))
    return {"backend": backend, "server": found.kind, "chosen": chosen,
            "path": PATHS.get(chosen)}


def choose_backend(cfg: Config) -> str:
    """``cfg.audio.backend``, with ``auto`` resolved (:func:`audio_choice`)."""
    return str(audio_choice(cfg)["chosen"])


def open_audio(cfg: Config) -> AudioIO:
    """The audio path ``cfg.audio.backend`` names (not started); its ``choice`` says what
    was found and chosen (:func:`audio_choice`: the status topic and ``stats`` show it)."""
    choice = audio_choice(cfg)
    backend = choice["chosen"]
    audio: SimAudio | AlsaAudio | PipeWireAudio | None
    if backend == "sim":
        from .sim_audio import SimAudio
        audio = SimAudio(cfg)
    elif backend == "alsa":
        from .alsa_audio import AlsaAudio
        audio = AlsaAudio(cfg)
    elif backend == "pipewire":
        from .pipewire_audio import PipeWireAudio
        audio = PipeWireAudio(cfg)
    else:
        audio = None
    if audio is not None:
        audio.choice = choice
        return audio
    raise AudioDeviceError(f"audio.backend {cfg.audio.backend!r}: use alsa, pipewire, auto "
                           "or sim")
