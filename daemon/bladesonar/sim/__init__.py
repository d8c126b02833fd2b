"""Scene simulator: a 2-D room, a rotating fan and a co-located speaker+microphone,
rendered as the pulsed-sonar recording the daemon would capture, with exact truth.

``scene`` (geometry and validation), ``geometry`` (ray paths), ``schedule`` (rate vs time)
and ``render`` (streaming audio) are pure; scene files are read at the edge,
:func:`bladesonar.io.scene_file.load_scene`.
"""

from __future__ import annotations

from .scene import Scene

__all__ = ["Scene"]
