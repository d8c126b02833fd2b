"""Ray paths against closed forms: perpendicular feet, mirror images, Fermat's principle,
segment tests for wall echoes and shadowing, and the paper's cw/ccw mirror ambiguity."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bladesonar.sim import Scene, geometry

SQUARE6 = [[0, 0], [6, 0], [6, 6], [0, 6]]


def scene(vertices=SQUARE6, sensor=(1, 1), centre=(3, 3), *, blades=1, length=1.0, hub=0.0,
          reflection=0.5, **fan) -> Scene:
    return Scene.from_mapping(dict(
        room=dict(vertices=vertices, reflection=reflection), sensor=list(sensor),
        fan=dict(centre=list(centre), blades=blades, blade_length_m=length, hub_radius_m=hub,
                 **fan)))


def of_kind(p: geometry.Paths, kind: str, wall: int | None = None):
    m = p.kind == kind
    if wall is not None:
        m &= p.wall == wall
    return p.length_m[m], p.gain[m]


def _side(u: np.ndarray, q: np.ndarray) -> float:
    """Which side of the blade line through the centre (3, 3) along ``u`` the point is on."""
    return float(np.sign(u[0] * (q[1] - 3) - u[1] * (q[0] - 3)))


# ---------------------------------------------------------------- direct blade echo

@pytest.mark.parametrize("deg", [91.0, 95.0, 100.0, 105.0, 109.0])
def test_direct_echo_range_is_perpendicular_distance(deg):
    # sensor 3 m from the centre along -x; blade foot t = -3 cos(theta) must lie in [0, 1]
    s = scene([[0, 0], [10, 0], [10, 10], [0, 10]], sensor=(2, 5), centre=(5, 5))
    p = geometry.paths(s, math.radians(deg), wall_bounces=False)
    L, g = of_kind(p, "blade")
    h = 3 * abs(math.sin(math.radians(deg)))
    assert len(L) == 1
    assert L[0] / 2 == pytest.approx(h, abs=1e-12)
    assert g[0] == pytest.approx(1.0 / h ** 2, rel=1e-12)


@pytest.mark.parametrize("deg", [0.0, 45.0, 80.0, 89.0, 111.0, 180.0, 300.0])
def test_no_direct_echo_when_the_foot_is_off_the_blade(deg):
    s = scene([[0, 0], [10, 0], [10, 10], [0, 10]], sensor=(2, 5), centre=(5, 5))
    p = geometry.paths(s, math.radians(deg), wall_bounces=False)
    assert len(of_kind(p, "blade")[0]) == 0


def test_blade_reflects_on_both_faces():
    s = scene([[0, 0], [10, 0], [10, 10], [0, 10]], sensor=(2, 5), centre=(5, 5))
    a = of_kind(geometry.paths(s, math.radians(100)), "blade")[0]
    b = of_kind(geometry.paths(s, math.radians(260)), "blade")[0]   # mirrored: other face
    assert a[0] == pytest.approx(b[0], abs=1e-12)


# ---------------------------------------------------------------- one wall bounce

def test_one_bounce_length_is_distance_via_the_mirror_images():
    # blade along the line y = x (theta = 225 deg, from (3, 3) towards the origin);
    # sensor S = (1, 2), its image in wall x = 0 is S' = (-1, 2), S mirrored in the blade
    # line is S* = (2, 1): path length |S* - S'| = sqrt(10); specular point (1.25, 1.25).
    s = scene(sensor=(1, 2), centre=(3, 3), length=2.6)
    p = geometry.paths(s, math.radians(225))
    for kind in ("wall_blade", "blade_wall"):
        L, g = of_kind(p, kind, wall=3)
        assert len(L) == 1
        assert L[0] == pytest.approx(math.sqrt(10), abs=1e-12)
        leg1 = math.hypot(1.25 + 1, 1.25 - 2)     # image -> specular point (unfolded)
        leg2 = math.hypot(1.25 - 1, 1.25 - 2)     # specular point -> sensor
        assert g[0] == pytest.approx(0.5 * 1.0 / (leg1 * leg2), rel=1e-12)


@pytest.mark.slow
def test_one_bounce_paths_obey_fermat():
    """Where a wall_blade path exists its length is the shortest image->blade->sensor route
    (found by brute force along the blade), and it exists exactly where that minimum is
    strictly inside the blade with the image and the sensor on the same side."""
    s = scene(sensor=(1, 2), centre=(3, 3), length=2.6)
    S, img = np.array([1.0, 2.0]), np.array([-1.0, 2.0])   # image in wall 3 (x = 0)
    r = np.linspace(0, 2.6, 260001)
    checked = 0
    for deg in np.arange(0, 360, 3.0):
        u = np.array([math.cos(math.radians(deg)), math.sin(math.radians(deg))])
        X = np.array([3.0, 3.0]) + r[:, None] * u
        f = np.hypot(*(X - img).T) + np.hypot(*(X - S).T)
        i = int(np.argmin(f))
        # the wall leg must cross wall 3 (x = 0, 0 <= y <= 6)
        y_wall = img[1] + (X[i][1] - img[1]) * (0 - img[0]) / (X[i][0] - img[0])
        expect = (0 < i < len(r) - 1 and _side(u, S) == _side(u, img) != 0 and 0 <= y_wall <= 6)
        L, _ = of_kind(geometry.paths(s, math.radians(deg)), "wall_blade", wall=3)
        assert (len(L) == 1) == expect, deg
        if expect:
            assert L[0] == pytest.approx(f[i], abs=1e-6)
            checked += 1
    assert checked >= 3


# ---------------------------------------------------------------- walls

L_ROOM = [[0, 0], [4.5, 0], [4.5, 2.5], [2.5, 2.5], [2.5, 4.0], [0, 4.0]]


def test_wall_echo_only_when_the_foot_is_on_the_wall_segment():
    s = scene(L_ROOM, sensor=(0.25, 0.25), centre=(1.5, 1.5), length=0.5)
    p = geometry.paths(s, 0.0)
    walls = dict(zip(p.wall[p.kind == "wall"], p.length_m[p.kind == "wall"] / 2, strict=True))
    # wall 2 (y = 2.5, x 2.5..4.5) and wall 3 (x = 2.5, y 2.5..4): feet off the segments
    assert walls == pytest.approx({0: 0.25, 1: 4.25, 4: 3.75, 5: 0.25})
    s2 = scene(L_ROOM, sensor=(3.0, 0.25), centre=(1.5, 1.5), length=0.5)
    p2 = geometry.paths(s2, 0.0)
    walls2 = dict(zip(p2.wall[p2.kind == "wall"], p2.length_m[p2.kind == "wall"] / 2, strict=True))
    assert walls2 == pytest.approx({0: 0.25, 1: 1.5, 2: 2.25, 5: 3.0})  # wall 4 now off
    # amplitude of a wall echo: one unfolded leg of 2d
    assert p2.gain[(p2.kind == "wall") & (p2.wall == 2)][0] == pytest.approx(0.5 / 4.5)


def test_a_wall_shadows_a_wall_echo():
    # a slot cut in from the left wall at y = 3.5..4 blocks the sensor's view of the top wall
    slot = [[0, 0], [6, 0], [6, 6], [0, 6], [0, 4], [3, 4], [3, 3.5], [0, 3.5]]
    s = scene(slot, sensor=(1, 1), centre=(4.5, 1.5), length=0.5)
    p = geometry.paths(s, 0.0)
    w = dict(zip(p.wall[p.kind == "wall"], p.length_m[p.kind == "wall"] / 2, strict=True))
    assert 2 not in w                         # top wall y = 6: blocked by the slot
    assert w[6] == pytest.approx(2.5)         # the slot's lower face y = 3.5
    open_room = scene(sensor=(1, 1), centre=(4.5, 1.5), length=0.5)
    q = geometry.paths(open_room, 0.0)
    assert of_kind(q, "wall", wall=2)[0][0] / 2 == pytest.approx(5.0)


def test_a_blade_shadows_a_wall_echo_and_echoes_itself():
    s = scene(sensor=(2, 1), centre=(1.5, 3), length=1.0)   # blade spans x 1.5..2.5 at 0 rad
    crossing = geometry.paths(s, 0.0)
    assert len(of_kind(crossing, "wall", wall=2)[0]) == 0     # top wall y = 6 blocked
    assert of_kind(crossing, "blade")[0][0] / 2 == pytest.approx(2.0)
    clear = geometry.paths(s, math.pi / 2)                     # blade along x = 1.5
    assert of_kind(clear, "wall", wall=2)[0][0] / 2 == pytest.approx(5.0)


def test_blades_shadow_each_others_direct_echo():
    """K = 6: a direct echo exists exactly where the perpendicular foot is on the blade
    and no other blade crosses the sight line (brute force, independent of the code)."""
    K, hub, L = 6, 0.1, 1.5
    S, C = np.array([1.0, 3.2]), np.array([3.0, 3.0])
    s = scene(sensor=tuple(S), centre=tuple(C), blades=K, length=L, hub=hub)
    shadowed = 0
    for th in np.linspace(0, 2 * np.pi, 720, endpoint=False):
        t = geometry.path_table(s, np.array([th]), wall_bounces=False)
        for j in range(K):
            a = th + 2 * np.pi * j / K
            u = np.array([math.cos(a), math.sin(a)])
            foot_t = float(np.dot(S - C, u))
            if not hub < foot_t < hub + L:
                expect = False
            else:
                foot = C + foot_t * u
                blocked = False
                for o in range(K):
                    if o != j:
                        b = th + 2 * np.pi * o / K
                        v = np.array([math.cos(b), math.sin(b)])
                        blocked |= _cross_open(S, foot, C + hub * v, C + (hub + L) * v)
                shadowed += blocked
                expect = not blocked
            col = np.nonzero((t.kind == "blade") & (t.blade == j))[0][0]
            assert bool(t.valid[0, col]) == expect, (th, j)
    assert shadowed > 5


def _cross_open(p1, p2, q1, q2) -> bool:
    d, e = p2 - p1, q2 - q1
    den = d[0] * e[1] - d[1] * e[0]
    if abs(den) < 1e-15:
        return False
    w = q1 - p1
    t = (w[0] * e[1] - w[1] * e[0]) / den
    u = (w[0] * d[1] - w[1] * d[0]) / den
    return 1e-9 < t < 1 - 1e-9 and 0 <= u <= 1


# ---------------------------------------------------------------- degenerate cases

def test_sensor_at_the_fan_centre_has_no_specular_blade_paths():
    s = scene(sensor=(3, 3), centre=(3, 3), blades=4, length=1.0)
    t = geometry.path_table(s, np.linspace(0, 2 * np.pi, 97))
    assert not t.valid[:, np.isin(t.kind, geometry.FAN_KINDS)].any()
    assert np.all(np.isfinite(t.gain))


def test_sensor_under_a_blade_has_finite_gain():
    s = scene(sensor=(3.5, 3), centre=(3, 3), blades=4, length=1.0)
    t = geometry.path_table(s, np.linspace(0, 2 * np.pi, 1001))
    assert np.all(np.isfinite(t.gain))
    assert t.gain.max() <= 1 / geometry.MIN_LEG_M ** 2 + 1e-9


# ---------------------------------------------------------------- cw / ccw ambiguity

def fan_profile(s: Scene, angle: float, wall_bounces: bool) -> np.ndarray:
    """Smoothed range profile of the fan paths only (one-way range 0..6 m, 1 cm bins)."""
    p = geometry.paths(s, angle, wall_bounces=wall_bounces)
    m = p.is_fan
    r = np.arange(0, 6, 0.01)
    return (p.gain[m][:, None] * np.exp(-((r[None, :] - p.length_m[m][:, None] / 2) / 0.02)
                                        ** 2)).sum(axis=0)


def series(s, start, sign, wall_bounces, n=120):
    step = 2 * np.pi / s.K / n
    return np.array([fan_profile(s, start + sign * i * step, wall_bounces) for i in range(n)])


@pytest.mark.slow
def test_cw_and_ccw_are_mirror_images_without_wall_bounces_but_differ_with_them():
    from pathlib import Path

    from bladesonar.io.scene_file import load_scene

    s = load_scene(Path(__file__).resolve().parents[1] / "config/scenes/paper-room.yaml")
    S, C = np.array(s.sensor), np.array(s.fan_centre)
    beta = math.atan2(*(S - C)[::-1])            # direction centre -> sensor
    a0 = 0.3
    mirror = 2 * beta - a0                       # mirror start about the sensor-centre line
    ccw = series(s, a0, +1, False)
    cw = series(s, mirror, -1, False)
    assert np.abs(ccw).max() > 0
    assert np.allclose(ccw, cw, atol=1e-9 * np.abs(ccw).max())

    ccw_m = series(s, a0, +1, True)
    norm = np.linalg.norm(ccw_m)
    # no start angle makes the cw multipath series equal the ccw one
    best = min(np.linalg.norm(series(s, mirror + d, -1, True) - ccw_m) / norm
               for d in np.linspace(-0.05, 0.05, 11))
    assert best > 0.3
    starts = np.linspace(0, 2 * np.pi / s.K, 24, endpoint=False)
    assert min(np.linalg.norm(series(s, a, -1, True, n=120) - ccw_m) / norm
               for a in starts) > 0.3
