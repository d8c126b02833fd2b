"""Echo paths of a 3-D scene: image sources in a box room, pitched plate blades (pure).

The same per-pulse path list as the 2-D ``geometry`` (:class:`geometry.PathTable`), so
the renderer's time model, nuisances and truth serve both. Kinds:

``coupling``            speaker -> microphone, length 0
``wall``                sensor -> surface -> sensor (first-order image source, 6 surfaces)
``wall2``               two surfaces (second-order image sources: the static room's
                        next echoes, 18 in a box)
``blade``               sensor -> blade -> sensor: the plate's specular lobe
``blade_diffuse``       the weak diffuse echo from the plate's centre
``wall_blade``, ``blade_wall``   one surface bounce on the way out or back, specular
``wall_blade_diffuse``, ``blade_wall_diffuse``   the same, diffuse

Plate model (physical-optics-like). A path runs from X to Y (the sensor or its image in a
surface). Its specular point is where X -> mirror(Y) crosses the plate's plane; clamped
to the rectangle, it gives the reflection point q and the path length |X - q| + |q - Y|.
The amplitude is ``rho * area / (lambda * |X - q| * |q - Y|)`` (a small plate's peak in
physical optics: it is smaller than its Fresnel zone) times a Gaussian lobe in the two
angles between the bisector of q->X and q->Y and the plate normal, measured along the
plate's length and its chord, each with standard deviation ``lambda / (2 * side)``: a
long blade's lobe is narrow along its length, a narrow chord's broad across it. Inside the
rectangle the bisector is the normal and the lobe is 1. Both faces reflect; a path that
would pass through the plate has no specular part. The diffuse part adds
``diffuse * sqrt(|cos_in * cos_out|)`` of the same amplitude from the plate's centre.

Not modelled: shadowing (blades near the ceiling, the sensor below), blade-to-blade
paths, the hub and the motor housing, surfaces' frequency dependence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .geometry import MIN_LEG_M, Paths, PathTable
from .scene3d import SURFACES, Scene3D

KINDS = ("coupling", "wall", "wall2", "blade", "blade_diffuse", "wall_blade",
         "blade_wall", "wall_blade_diffuse", "blade_wall_diffuse")
FAN_KINDS = ("blade", "blade_diffuse", "wall_blade", "blade_wall", "wall_blade_diffuse",
             "blade_wall_diffuse")
_EPS = 1e-12


@dataclass(frozen=True)
class SensorImages:
    """The sensor's images: ``first`` (6, 3) in each surface; ``second`` (n, 3) in two,
    with their surfaces ``pairs`` (n, 2)."""

    first: np.ndarray
    second: np.ndarray
    pairs: np.ndarray


def _mirror(p: np.ndarray, surface: int, size: np.ndarray) -> np.ndarray:
    axis, far = divmod(surface, 2)
    if surface >= 4:                        # floor (4) or ceiling (5): the z axis
        axis, far = 2, surface - 4
    q = np.array(p, dtype=np.float64)
    q[axis] = 2.0 * size[axis] * far - q[axis]
    return q


def sensor_images(scene: Scene3D) -> SensorImages:
    size = np.asarray(scene.size, dtype=np.float64)
    S = np.asarray(scene.sensor, dtype=np.float64)
    first = np.stack([_mirror(S, i, size) for i in range(6)])
    second, pairs = [], []
    for i in range(6):
        for j in range(6):
            if i == j:
                continue
            ai, aj = _axis(i), _axis(j)
            if ai != aj and j < i:          # perpendicular surfaces: one image per pair
                continue
            second.append(_mirror(first[i], j, size))
            pairs.append((i, j))
    return SensorImages(first, np.asarray(second), np.asarray(pairs, dtype=np.int64))


def max_path_m(scene: Scene3D) -> float:
    """An upper bound of every path's length (the renderer's look-back), m."""
    S, C = np.asarray(scene.sensor), np.asarray(scene.fan_centre)
    imgs = sensor_images(scene)
    far_fan = float(np.max(np.linalg.norm(imgs.first - C, axis=1))) + scene.tip_radius_m
    near_fan = float(np.linalg.norm(S - C)) + scene.tip_radius_m
    walls = float(np.max(np.linalg.norm(np.concatenate([imgs.first, imgs.second]) - S,
                                        axis=1)))
    return max(walls, near_fan + far_fan, 2 * near_fan)


def _axis(surface: int) -> int:
    return 2 if surface >= 4 else surface // 2


@dataclass(frozen=True)
class Plates:
    """The K blades at P fan angles: centre ``pc``, unit radial axis ``r``, chord ``c``
    and normal ``n`` (each (P, K, 3)); half length ``a`` and half chord ``b``, m."""

    pc: np.ndarray
    r: np.ndarray
    c: np.ndarray
    n: np.ndarray
    a: float
    b: float

    @classmethod
    def at(cls, scene: Scene3D, th: np.ndarray) -> Plates:
        K = scene.K
        C = np.asarray(scene.fan_centre, dtype=np.float64)
        phi = th[:, None] + 2.0 * np.pi * np.arange(K)[None, :] / K
        zero = np.zeros_like(phi)
        # ccw seen from below turns +x towards -y
        u = np.stack([np.cos(phi), -np.sin(phi), zero], axis=-1)
        t = np.stack([-np.sin(phi), -np.cos(phi), zero], axis=-1)
        z = np.array([0.0, 0.0, 1.0])
        dr, be = math.radians(scene.droop_deg), math.radians(scene.pitch_deg)
        r = math.cos(dr) * u - math.sin(dr) * z
        c = math.cos(be) * t + math.sin(be) * z
        c = c - np.sum(c * r, axis=-1, keepdims=True) * r
        c /= np.linalg.norm(c, axis=-1, keepdims=True)
        n = np.cross(r, c)
        mid = 0.5 * (scene.hub_radius_m + scene.tip_radius_m)
        return cls(C + mid * r, r, c, n, 0.5 * scene.blade_length_m, 0.5 * scene.chord_m)


def plate_echo(plates: Plates, X: np.ndarray, Y: np.ndarray, *, area: float,
               wavelength: float, diffuse: float, rho: float | np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Paths X -> plate -> Y for every plate (X, Y broadcastable to (..., 3)).

    Returns (specular length, specular gain, specular valid, diffuse length, diffuse gain),
    each broadcast over the plates' (P, K) and X's leading shape."""
    pc, r, c, n = plates.pc, plates.r, plates.c, plates.n
    hX = np.sum((X - pc) * n, axis=-1)
    hY = np.sum((Y - pc) * n, axis=-1)
    ok = hX * hY > _EPS
    Ystar = Y - 2.0 * hY[..., None] * n
    lam = hX / np.where(ok, hX + hY, 1.0)
    f = X + lam[..., None] * (Ystar - X)
    a = np.clip(np.sum((f - pc) * r, axis=-1), -plates.a, plates.a)
    b = np.clip(np.sum((f - pc) * c, axis=-1), -plates.b, plates.b)
    q = pc + a[..., None] * r + b[..., None] * c
    d1 = np.linalg.norm(X - q, axis=-1)
    d2 = np.linalg.norm(Y - q, axis=-1)
    ua = (X - q) / np.maximum(d1, _EPS)[..., None]
    ub = (Y - q) / np.maximum(d2, _EPS)[..., None]
    h = ua + ub
    h /= np.maximum(np.linalg.norm(h, axis=-1), _EPS)[..., None]
    ar = np.arcsin(np.clip(np.sum(h * r, axis=-1), -1.0, 1.0))
    ac = np.arcsin(np.clip(np.sum(h * c, axis=-1), -1.0, 1.0))
    sr, sc = wavelength / (4.0 * plates.a), wavelength / (4.0 * plates.b)
    lobe = np.exp(-0.5 * ((ar / sr) ** 2 + (ac / sc) ** 2))
    peak = rho * area / wavelength
    g_spec = np.where(ok, peak * lobe / (np.maximum(d1, MIN_LEG_M) * np.maximum(d2, MIN_LEG_M)),
                      0.0)
    e1 = np.linalg.norm(X - pc, axis=-1)
    e2 = np.linalg.norm(Y - pc, axis=-1)
    cos1 = np.abs(np.sum((X - pc) * n, axis=-1)) / np.maximum(e1, _EPS)
    cos2 = np.abs(np.sum((Y - pc) * n, axis=-1)) / np.maximum(e2, _EPS)
    g_diff = diffuse * peak * np.sqrt(cos1 * cos2) / (np.maximum(e1, MIN_LEG_M)
                                                      * np.maximum(e2, MIN_LEG_M))
    return d1 + d2, g_spec, ok & (g_spec > 0), e1 + e2, g_diff


def path_table(scene: Scene3D, angles: np.ndarray, *, wall_bounces: bool = True) -> PathTable:
    """Every path at fan angles ``angles`` (P,), radians ccw seen from below. Columns:
    coupling, 6 walls, the second-order images, K blades, K diffuse, then (if
    ``wall_bounces``) for each of wall_blade, blade_wall, wall_blade_diffuse,
    blade_wall_diffuse K*6 columns (blade-major)."""
    th = np.asarray(angles, dtype=np.float64).reshape(-1)
    P, K = len(th), scene.K
    S = np.asarray(scene.sensor, dtype=np.float64)
    imgs = sensor_images(scene)
    rho = np.asarray(scene.surface_reflection, dtype=np.float64)
    lengths, gains, valid, kinds, blade, wall = [], [], [], [], [], []

    def add(length: np.ndarray, gain: np.ndarray, ok: np.ndarray, kind: str,
            b: list[int], w: list[int]) -> None:
        n = length.shape[-1]
        lengths.append(np.broadcast_to(length, (P, n)))
        gains.append(np.broadcast_to(gain, (P, n)))
        valid.append(np.broadcast_to(ok, (P, n)))
        kinds.extend([kind] * n)
        blade.extend(b)
        wall.extend(w)

    add(np.zeros((1, 1)), np.full((1, 1), scene.coupling_gain), np.ones((1, 1), bool),
        "coupling", [-1], [-1])
    L1 = np.linalg.norm(imgs.first - S, axis=1)
    add(L1[None], (rho / np.maximum(L1, MIN_LEG_M))[None], (L1 > 0)[None], "wall",
        [-1] * 6, list(range(6)))
    L2 = np.linalg.norm(imgs.second - S, axis=1)
    g2 = rho[imgs.pairs[:, 0]] * rho[imgs.pairs[:, 1]] / np.maximum(L2, MIN_LEG_M)
    add(L2[None], g2[None], (L2 > 0)[None], "wall2", [-1] * len(L2),
        [int(6 * i + j) for i, j in imgs.pairs])
    plates = Plates.at(scene, th)
    area = scene.blade_length_m * scene.chord_m
    kw = dict(area=area, wavelength=scene.lobe_wavelength_m, diffuse=scene.diffuse)
    ls, gs, oks, ld, gd = plate_echo(plates, S, S, rho=scene.blade_reflectivity, **kw)
    ks = list(range(K))
    add(ls, gs, oks, "blade", ks, [-1] * K)
    add(ld, gd, gd > 0, "blade_diffuse", ks, [-1] * K)
    if wall_bounces:
        # plates (P, K, 1, 3) against the 6 images (6, 3): (P, K, 6)
        pl = Plates(plates.pc[:, :, None], plates.r[:, :, None], plates.c[:, :, None],
                    plates.n[:, :, None], plates.a, plates.b)
        ls, gs, oks, ld, gd = plate_echo(pl, imgs.first, S,
                                         rho=scene.blade_reflectivity * rho, **kw)
        bw = [int(b) for b in np.repeat(np.arange(K), 6)]
        ww = [int(w) for w in np.tile(np.arange(6), K)]
        for name in ("wall_blade", "blade_wall"):   # the same route both ways round
            add(ls.reshape(P, 6 * K), gs.reshape(P, 6 * K), oks.reshape(P, 6 * K), name,
                bw, ww)
        for name in ("wall_blade_diffuse", "blade_wall_diffuse"):
            add(ld.reshape(P, 6 * K), gd.reshape(P, 6 * K), (gd > 0).reshape(P, 6 * K),
                name, bw, ww)
    ok_all = np.concatenate(valid, axis=1)
    length = np.where(ok_all, np.concatenate(lengths, axis=1), np.nan)
    gain = np.where(ok_all, np.concatenate(gains, axis=1), 0.0)
    return PathTable(length, gain, ok_all, np.array(kinds),
                     np.array(blade, dtype=np.int64), np.array(wall, dtype=np.int64))


def paths(scene: Scene3D, fan_angle_rad: float, *, wall_bounces: bool = True) -> Paths:
    """The valid paths at one fan angle."""
    return path_table(scene, np.array([float(fan_angle_rad)]),
                      wall_bounces=wall_bounces).row(0)


__all__ = ["FAN_KINDS", "KINDS", "SURFACES", "Plates", "max_path_m", "path_table", "paths",
           "plate_echo", "sensor_images"]
