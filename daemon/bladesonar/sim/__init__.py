"""Scene simulator: a 2-D room, a rotating fan and a co-located speaker+microphone,
rendered as the pulsed-sonar recording the daemon would capture, with exact truth.

``scene`` (geometry and validation), ``geometry`` (ray paths), ``schedule`` (rate vs time)
and ``render`` (streaming audio) are pure; ``load_scene`` is the one file edge.
"""

from __future__ import annotations

from ..io.scene_file import load_scene
from .scene import Scene

__all__ = ["Scene", "load_scene"]
