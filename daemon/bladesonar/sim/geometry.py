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

KINDS = ("coupling", "wall", "blade", "wall_blade", "blade_wall")
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
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def _norm(a: np.ndarray) -> np.ndarray:
    return np.hypot(a[..., 0], a[..., 1])


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
    return hit.any(axis=-1)


def path_table(scene: Scene, angles: np.ndarray, *, wall_bounces: bool = True) -> PathTable:
    """All candidate paths for fan angles ``angles`` (P,), vectorised over angles, blades
    and walls. Column order: coupling, W walls, K blades, then (if ``wall_bounces``)
    K*W wall_blade and K*W blade_wall (blade-major)."""
    th = np.asarray(angles, dtype=np.float64).reshape(-1)
    P, K = len(th), scene.K
    A, B = scene.wall_a, scene.wall_b
    W = len(A)
    nrm = scene.wall_normals
    rho_w = np.asarray(scene.wall_reflection, dtype=np.float64)
    rho_b = float(scene.blade_reflectivity)
    S = np.asarray(scene.sensor, dtype=np.float64)
    C = np.asarray(scene.fan_centre, dtype=np.float64)
    r0, r1 = scene.hub_radius_m, scene.tip_radius_m

    # blades: unit direction u, normal nu, end points; (P, K, 2)
    phi = th[:, None] + 2.0 * np.pi * np.arange(K)[None, :] / K
    u = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    nu = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    e0, e1 = C + r0 * u, C + r1 * u

    # obstacles per angle: walls then blades; (P, n_obst, 2)
    n_obst = W + K
    q1 = np.concatenate([np.broadcast_to(A, (P, W, 2)), e0], axis=1)
    q2 = np.concatenate([np.broadcast_to(B, (P, W, 2)), e1], axis=1)
    eyeW = np.zeros((W, n_obst), bool)
    eyeW[np.arange(W), np.arange(W)] = True
    eyeK = np.zeros((K, n_obst), bool)
    eyeK[np.arange(K), W + np.arange(K)] = True

    # --- static wall echoes (W,)
    wl = B - A
    wl2 = np.maximum(_dot(wl, wl), 1e-300)
    delta = _dot(S - A, nrm)  # sensor height above each wall's inner face
    foot = S - delta[:, None] * nrm
    s_foot = _dot(foot - A, wl) / wl2
    w_ok = (delta > _EPS) & (s_foot >= 0) & (s_foot <= 1)
    w_ok = w_ok[None, :] & ~_blocked(np.broadcast_to(S, (P, W, 2)),
                                     np.broadcast_to(foot, (P, W, 2)), q1[:, None],
                                     q2[:, None], eyeW[None])
    w_len = np.broadcast_to(2 * delta, (P, W))
    w_gain = rho_w / np.maximum(2 * delta, MIN_LEG_M)

    # --- direct blade echoes (P, K)
    dS = S - C
    t_s = _dot(dS[None, None, :], u)
    h_s = _dot(dS[None, None, :], nu)
    pb = C + t_s[..., None] * u
    b_ok = (np.abs(h_s) > _EPS) & (t_s >= r0) & (t_s <= r1)
    b_ok &= ~_blocked(np.broadcast_to(S, pb.shape), pb, q1[:, None], q2[:, None], eyeK[None])
    b_len = 2 * np.abs(h_s)
    b_gain = rho_b / np.maximum(np.abs(h_s), MIN_LEG_M) ** 2

    lengths = [np.zeros((P, 1)), w_len, b_len]
    gains = [np.full((P, 1), scene.coupling_gain), np.broadcast_to(w_gain, (P, W)), b_gain]
    valid = [np.ones((P, 1), bool), w_ok, b_ok]
    kind = ["coupling"] + ["wall"] * W + ["blade"] * K
    bl = [-1] * (1 + W) + list(range(K))
    wa = [-1] + list(range(W)) + [-1] * K

    if wall_bounces:
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
        exW = np.broadcast_to(eyeW[None, :, :], (K, W, n_obst))
        exK = np.broadcast_to(eyeK[:, None, :], (K, W, n_obst))
        Sb = np.broadcast_to(S, wp.shape)
        Q1, Q2 = q1[:, None, None], q2[:, None, None]
        ok &= ~_blocked(Sb, wp, Q1, Q2, exW[None])
        ok &= ~_blocked(wp, pt, Q1, Q2, (exW | exK)[None])
        ok &= ~_blocked(pt, Sb, Q1, Q2, exK[None])
        leg1 = _norm(pt - img)
        leg2 = _norm(pt - S)
        wb_len = _norm(s_star - img)
        wb_gain = rho_w[None, None, :] * rho_b / (np.maximum(leg1, MIN_LEG_M)
                                                  * np.maximum(leg2, MIN_LEG_M))
        for name in ("wall_blade", "blade_wall"):
            lengths.append(wb_len.reshape(P, K * W))
            gains.append(wb_gain.reshape(P, K * W))
            valid.append(ok.reshape(P, K * W))
            kind += [name] * (K * W)
            bl += list(np.repeat(np.arange(K), W))
            wa += list(np.tile(np.arange(W), K))

    valid_a = np.concatenate(valid, axis=1)
    length = np.where(valid_a, np.concatenate(lengths, axis=1), np.nan)
    gain = np.where(valid_a, np.concatenate(gains, axis=1), 0.0)
    return PathTable(length, gain, valid_a, np.array(kind), np.array(bl, dtype=np.int64),
                     np.array(wa, dtype=np.int64))
