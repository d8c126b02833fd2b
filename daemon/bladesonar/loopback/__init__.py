"""Loopback self-test: a simulated room between the daemon's ALSA playback and capture.

``alsaconf`` writes the private PCMs on two FIFOs; ``room`` answers what the daemon plays
with the scene's echoes. Command: ``bladesonar room`` (docs/audio.md).
"""

from .alsaconf import CAP_PCM, PLAY_PCM, alsa_env, write_alsa_config
from .room import Room, RoomStats

__all__ = ["CAP_PCM", "PLAY_PCM", "Room", "RoomStats", "alsa_env", "write_alsa_config"]
