"""A person walking through the room: a moving point reflector (pure).

They enter at the room's left edge (smallest x) at ``walker_start_s`` and walk along
``y = walker_y_m`` at ``walker_speed_m_s`` until the right edge; while inside the room
they echo straight back like a blade's direct echo, gain ``walker_reflectivity / d^2``
at distance d (no wall bounces, no shadowing: a disturbance, not a second target).
"""

from __future__ import annotations

import numpy as np

from ..sim.geometry import MIN_LEG_M
from .nuisances import Nuisances
from .scene import Scene, _inside


def walker_line_y(nz: Nuisances, scene: Scene) -> float:
    """The y of the line walked: given, or halfway between the sensor and the fan."""
    if nz.walker_y_m >= 0:
        return float(nz.walker_y_m)
    return 0.5 * (scene.sensor[1] + scene.fan_centre[1])


def walker_paths(nz: Nuisances, scene: Scene, t: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(path length m, gain, present) of the person's echo at emission times ``t``."""
    t = np.asarray(t, dtype=np.float64)
    n = len(t)
    if nz.walker_speed_m_s <= 0:
        return np.zeros(n), np.zeros(n), np.zeros(n, bool)
    V = scene.wall_a
    x0, x1 = float(V[:, 0].min()), float(V[:, 0].max())
    y = walker_line_y(nz, scene)
    x = x0 + nz.walker_speed_m_s * (t - nz.walker_start_s)
    present = (t >= nz.walker_start_s) & (x <= x1)
    present &= np.array([_inside(np.array([xi, y]), V) for xi in x]) if n else present
    d = np.maximum(np.hypot(x - scene.sensor[0], y - scene.sensor[1]), MIN_LEG_M)
    return 2.0 * d, np.where(present, nz.walker_reflectivity / (d * d), 0.0), present
