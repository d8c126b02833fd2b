"""Ray paths from the sensor back to itself: image sources, specular points, shadowing (pure).

Paths with at most one specular wall bounce, as in the paper's simulation:

``coupling``    speaker -> microphone directly, length 0 (the pulse's leading edge)
``wall``        sensor -> wall -> sensor (image source; the foot of the perpendicular must
                lie on the wall segment)
``blade``       sensor -> blade -> sensor (the foot of the perpendicular from the sensor
                onto the blade line must lie on the blade segment)
``wall_blade``  sensor -> wall -> blade -> sensor, and
``blade_wall``  the same route reversed (same length and gain; both arrive together)

A blade is a segment, reflecting on both faces, only at its specular point (angle of
incidence = angle of reflection, found by mirroring one end in the blade line; both ends
must be strictly on the same side of the line). Walls reflect on the room's inner face.
Every straight leg is tested against every wall and blade it does not start or end on;
a crossing removes the path (shadowing).

Amplitude, relative to the transmitted pulse: product of reflection coefficients divided
by the product of the leg lengths in metres (spherical spreading 1/r per leg, reference
distance 1 m). A leg is the straight run between the sensor and a blade *unfolded through
the wall mirror* (image-source method: a plane wall adds no spreading of its own), so
``wall`` has one leg of 2d, ``blade`` two legs of d, ``wall_blade`` the legs
|image - P| and |P - sensor|. Legs shorter than ``MIN_LEG_M`` count as ``MIN_LEG_M``.

Angles: see ``scene``; fan angle 0 puts blade 0 along +x, positive is ccw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Scene

FAN_KINDS = ("blade", "wall_blade", "blade_wall")
#: Near-field floor of a leg length in the 1/r spreading law (the sensor under a blade).
MIN_LEG_M = 0.05
_EPS = 1e-9


@dataclass(frozen=True)
class Paths:
    """Valid paths at one fan angle; arrays of equal length, float64 unless noted."""

    length_m: np.ndarray
    """Total there-and-back path length; one-way range = length_m / 2."""
    gain: np.ndarray
    """Amplitude relative to the transmitted pulse (see module docstring)."""
    kind: np.ndarray
    """str codes: coupling, wall, blade, wall_blade, blade_wall."""
    blade: np.ndarray
    """int, blade index or -1."""
    wall: np.ndarray
    """int, wall index or -1."""

    def delay_samples(self, speed_of_sound: float, sample_rate: float) -> np.ndarray:
        return self.length_m / speed_of_sound * sample_rate

    @property
    def is_fan(self) -> np.ndarray:
        return np.isin(self.kind, FAN_KINDS)


@dataclass(frozen=True)
class PathTable:
    """Every candidate path for many fan angles: rows = angles, columns = candidates.

    ``length_m`` and ``gain`` are (P, M); invalid (shadowed / not specular) entries have
    ``valid`` False, gain 0 and length NaN. ``kind``, ``blade``, ``wall`` are (M,).
    """

    length_m: np.ndarray
    gain: np.ndarray
    valid: np.ndarray
    kind: np.ndarray
    blade: np.ndarray
    wall: np.ndarray

    def row(self, i: int) -> Paths:
        v = self.valid[i]
        return Paths(self.length_m[i, v], self.gain[i, v], self.kind[v], self.blade[v],
                     self.wall[v])


def paths(scene: Scene, fan_angle_rad: float, *, wall_bounces: bool = True) -> Paths:
    """The valid paths at one fan angle (radians, ccw, blade 0 along +x at 0)."""
    return path_table(scene, np.array([float(fan_angle_rad)]),
                      wall_bounces=wall_bounces).row(0)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out: np.ndarray = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out: np.ndarray = a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]
    return out


def _norm(a: np.ndarray) -> np.ndarray:
    out: np.ndarray = np.hypot(a[..., 0], a[..., 1])
    return out


def _blocked(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray,
             exclude: np.ndarray) -> np.ndarray:
    """Whether the open segment p1->p2 crosses any obstacle segment q1->q2.

    p1, p2: (..., 2); q1, q2: (..., n_obst, 2) broadcastable; exclude: (..., n_obst) bool.
    Touching at the path's own end points does not count; grazing an obstacle's end does.
    """
    d = (p2 - p1)[..., None, :]
    e = q2 - q1
    w = q1 - p1[..., None, :]
    den = _cross(d, e)
    ok = np.abs(den) > 1e-15
    safe = np.where(ok, den, 1.0)
    t = _cross(w, e) / safe
    u = _cross(w, d) / safe
    hit = ok & (t > 1e-9) & (t < 1 - 1e-9) & (u >= -1e-12) & (u <= 1 + 1e-12) & ~exclude
    blocked: np.ndarray = hit.any(axis=-1)
    return blocked


def path_table(scene: Scene, angles: np.ndarray, *, wall_bounces: bool = True) -> PathTable:
    """All candidate paths for fan angles ``angles`` (P,), vectorised over angles, blades
    and walls. Column order: coupling, W walls, K blades, then (if ``wall_bounces``)
    K*W wall_blade and K*W blade_wall (blade-major)."""
    th = np.asarray(angles, dtype=np.float64).reshape(-1)
    blades = _BladeLines.at(scene, th)
    obstacles = _Obstacles.of(scene, blades)
    P, W, K = len(th), obstacles.walls, scene.K
    coupling = _Columns(np.zeros((P, 1)), np.full((P, 1), scene.coupling_gain),
                        np.ones((P, 1), bool), ["coupling"], [-1], [-1])
    groups = [coupling, _wall_echoes(scene, obstacles, P),
              _blade_echoes(scene, blades, obstacles)]
    if wall_bounces:
        length, gain, ok = _wall_blade_echoes(scene, blades, obstacles)
        for name in ("wall_blade", "blade_wall"):   # the same route both ways round
            groups.append(_Columns(length.reshape(P, K * W), gain.reshape(P, K * W),
                                   ok.reshape(P, K * W), [name] * (K * W),
                                   list(np.repeat(np.arange(K), W)),
                                   list(np.tile(np.arange(W), K))))
    valid = np.concatenate([g.valid for g in groups], axis=1)
    length = np.where(valid, np.concatenate([g.length for g in groups], axis=1), np.nan)
    gain = np.where(valid, np.concatenate([g.gain for g in groups], axis=1), 0.0)
    return PathTable(length, gain, valid, np.array([k for g in groups for k in g.kind]),
                     np.array([b for g in groups for b in g.blade], dtype=np.int64),
                     np.array([w for g in groups for w in g.wall], dtype=np.int64))


@dataclass(frozen=True)
class _Columns:
    """A group of candidate paths: (P, n) lengths, gains and validity at P angles, and
    each column's kind, blade and wall (-1: none)."""

    length: np.ndarray
    gain: np.ndarray
    valid: np.ndarray
    kind: list[str]
    blade: list[int]
    wall: list[int]


@dataclass(frozen=True)
class _BladeLines:
    """The K blades at P fan angles: unit direction ``u`` (hub to tip), normal ``nu`` and
    the hub and tip ends ``e0``, ``e1``, each (P, K, 2)."""

    u: np.ndarray
    nu: np.ndarray
    e0: np.ndarray
    e1: np.ndarray

    @classmethod
    def at(cls, scene: Scene, th: np.ndarray) -> _BladeLines:
        K = scene.K
        C = np.asarray(scene.fan_centre, dtype=np.float64)
        phi = th[:, None] + 2.0 * np.pi * np.arange(K)[None, :] / K
        u = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
        nu = np.stack([-u[..., 1], u[..., 0]], axis=-1)
        return cls(u, nu, C + scene.hub_radius_m * u, C + scene.tip_radius_m * u)


@dataclass(frozen=True)
class _Obstacles:
    """What can shadow a leg at each of P angles: the W walls then the K blades as
    segments ``q1`` -> ``q2`` (P, W + K, 2); ``own_wall`` (W, W + K) and ``own_blade``
    (K, W + K) mark the segment a leg starts or ends on (it does not shadow itself)."""

    q1: np.ndarray
    q2: np.ndarray
    own_wall: np.ndarray
    own_blade: np.ndarray

    @property
    def walls(self) -> int:
        return int(self.own_wall.shape[0])

    @classmethod
    def of(cls, scene: Scene, blades: _BladeLines) -> _Obstacles:
        A, B = scene.wall_a, scene.wall_b
        P, K = blades.u.shape[:2]
        W = len(A)
        n_obst = W + K
        q1 = np.concatenate([np.broadcast_to(A, (P, W, 2)), blades.e0], axis=1)
        q2 = np.concatenate([np.broadcast_to(B, (P, W, 2)), blades.e1], axis=1)
        own_wall = np.zeros((W, n_obst), bool)
        own_wall[np.arange(W), np.arange(W)] = True
        own_blade = np.zeros((K, n_obst), bool)
        own_blade[np.arange(K), W + np.arange(K)] = True
        return cls(q1, q2, own_wall, own_blade)


def _sensor_heights(scene: Scene) -> np.ndarray:
    """The sensor's height above each wall's inner face (W,), m."""
    return _dot(np.asarray(scene.sensor, dtype=np.float64) - scene.wall_a, scene.wall_normals)


def _wall_echoes(scene: Scene, obst: _Obstacles, P: int) -> _Columns:
    """Sensor -> wall -> sensor: valid where the foot of the perpendicular lies on the wall
    and neither leg is shadowed; the same at every fan angle but for the blades' shadows."""
    A, B, nrm = scene.wall_a, scene.wall_b, scene.wall_normals
    W = len(A)
    S = np.asarray(scene.sensor, dtype=np.float64)
    rho_w = np.asarray(scene.wall_reflection, dtype=np.float64)
    wl = B - A
    wl2 = np.maximum(_dot(wl, wl), 1e-300)
    delta = _sensor_heights(scene)
    foot = S - delta[:, None] * nrm
    s_foot = _dot(foot - A, wl) / wl2
    w_ok = (delta > _EPS) & (s_foot >= 0) & (s_foot <= 1)
    w_ok = w_ok[None, :] & ~_blocked(np.broadcast_to(S, (P, W, 2)),
                                     np.broadcast_to(foot, (P, W, 2)), obst.q1[:, None],
                                     obst.q2[:, None], obst.own_wall[None])
    w_len = np.broadcast_to(2 * delta, (P, W))
    w_gain = rho_w / np.maximum(2 * delta, MIN_LEG_M)
    return _Columns(w_len, np.broadcast_to(w_gain, (P, W)), w_ok, ["wall"] * W, [-1] * W,
                    list(range(W)))


def _blade_offsets(scene: Scene, blades: _BladeLines) -> tuple[np.ndarray, np.ndarray]:
    """The sensor's position along each blade line from the centre and its height off
    the line, each (P, K), m."""
    dS = np.asarray(scene.sensor, dtype=np.float64) - np.asarray(scene.fan_centre,
                                                                 dtype=np.float64)
    return _dot(dS[None, None, :], blades.u), _dot(dS[None, None, :], blades.nu)


def _blade_echoes(scene: Scene, blades: _BladeLines, obst: _Obstacles) -> _Columns:
    """Sensor -> blade -> sensor: valid where the foot of the perpendicular lies on the
    blade and the leg is not shadowed."""
    K = scene.K
    S = np.asarray(scene.sensor, dtype=np.float64)
    C = np.asarray(scene.fan_centre, dtype=np.float64)
    t_s, h_s = _blade_offsets(scene, blades)
    pb = C + t_s[..., None] * blades.u
    b_ok = (np.abs(h_s) > _EPS) & (t_s >= scene.hub_radius_m) & (t_s <= scene.tip_radius_m)
    b_ok &= ~_blocked(np.broadcast_to(S, pb.shape), pb, obst.q1[:, None], obst.q2[:, None],
                      obst.own_blade[None])
    b_len = 2 * np.abs(h_s)
    b_gain = float(scene.blade_reflectivity) / np.maximum(np.abs(h_s), MIN_LEG_M) ** 2
    return _Columns(b_len, b_gain, b_ok, ["blade"] * K, list(range(K)), [-1] * K)


def _wall_blade_echoes(scene: Scene, blades: _BladeLines,
                       obst: _Obstacles) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sensor -> wall -> blade -> sensor by the image source: length, gain and validity,
    each (P, K, W). Valid where the specular point lies on the blade, the unfolded leg
    passes through the wall segment and none of the three real legs is shadowed."""
    A, nrm = scene.wall_a, scene.wall_normals
    wl = scene.wall_b - A
    wl2 = np.maximum(_dot(wl, wl), 1e-300)
    S = np.asarray(scene.sensor, dtype=np.float64)
    C = np.asarray(scene.fan_centre, dtype=np.float64)
    r0, r1 = scene.hub_radius_m, scene.tip_radius_m
    u, nu = blades.u, blades.nu
    K, W = scene.K, obst.walls
    delta = _sensor_heights(scene)
    _, h_s = _blade_offsets(scene, blades)
    # sensor images in the walls (W, 2); broadcast to (P, K, W, 2)
    img = S - 2 * delta[:, None] * nrm
    h_i = _dot(img[None, None] - C, nu[:, :, None, :])            # (P, K, W)
    hs = h_s[..., None]
    same = (hs * h_i > 0) & (np.abs(hs) > _EPS) & (np.abs(h_i) > _EPS)
    s_star = S - 2 * hs[..., None] * nu[:, :, None, :]           # sensor mirrored in blade
    den = np.where(same, h_i + hs, 1.0)
    lam = np.where(same, h_i / den, 0.0)
    pt = img + lam[..., None] * (s_star - img)                   # specular point on blade
    t_p = _dot(pt - C, u[:, :, None, :])
    ok = same & (t_p >= r0) & (t_p <= r1) & (delta > _EPS)[None, None, :]
    # the unfolded leg image -> P must pass through the wall segment
    hp = _dot(pt - A, nrm)                                        # (P, K, W)
    ok &= hp > _EPS
    mu = delta / np.where(ok, delta + hp, 1.0)
    wp = img + mu[..., None] * (pt - img)                        # point on the wall
    s_w = _dot(wp - A, wl) / wl2
    ok &= (s_w >= 0) & (s_w <= 1)
    # shadowing on the three real legs
    n_obst = W + K
    exW = np.broadcast_to(obst.own_wall[None, :, :], (K, W, n_obst))
    exK = np.broadcast_to(obst.own_blade[:, None, :], (K, W, n_obst))
    Sb = np.broadcast_to(S, wp.shape)
    Q1, Q2 = obst.q1[:, None, None], obst.q2[:, None, None]
    ok &= ~_blocked(Sb, wp, Q1, Q2, exW[None])
    ok &= ~_blocked(wp, pt, Q1, Q2, (exW | exK)[None])
    ok &= ~_blocked(pt, Sb, Q1, Q2, exK[None])
    leg1 = _norm(pt - img)
    leg2 = _norm(pt - S)
    wb_len = _norm(s_star - img)
    rho_w = np.asarray(scene.wall_reflection, dtype=np.float64)
    wb_gain = rho_w[None, None, :] * float(scene.blade_reflectivity) / (
        np.maximum(leg1, MIN_LEG_M) * np.maximum(leg2, MIN_LEG_M))
    return wb_len, wb_gain, ok
