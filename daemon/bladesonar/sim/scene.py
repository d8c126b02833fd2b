"""The scene: a 2-D floor plan with walls, one co-located speaker+microphone and a fan (pure).

Conventions (contracts for plots and truth files):

- Coordinates in metres in the floor plan as drawn: x right, y up, seen from above.
- Wall i runs from vertex i to vertex i+1 (the last wall closes the polygon); walls
  reflect on the room's inner face only.
- Fan angle 0: blade 0 points along +x from the fan centre; blade j sits at
  angle + 2*pi*j/K. Positive angles and rates are counter-clockwise (ccw).
- A blade is the radial segment from ``hub_radius_m`` to ``hub_radius_m + blade_length_m``.

Blade count: the scene may state ``fan.blades``; it must then equal the config's
``scene.blades`` (the analysis divides the blade-phase rate by that K), else
``Scene.with_config`` raises ConfigError. A scene without it takes the config's K.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, NoReturn, Protocol, TypeVar

import numpy as np

from .. import schema
from ..errors import ConfigError
from ..schema import opt
from . import nuisances as _nuisances
from . import schedule as _schedule

if TYPE_CHECKING:
    from ..config import Config

#: K used by ``geometry`` when neither the scene nor a config gives one (config default).
DEFAULT_BLADES = 4
#: The sensor must sit at least this far inside every wall.
MIN_WALL_CLEARANCE_M = 1e-3

#: Most walls (vertices) a room may have: the wall checks are quadratic and the echo paths
#: grow with the walls; 5000 vertices once made simulate run for minutes.
MAX_WALLS = 64


@dataclass(frozen=True)
class Scene:
    """Geometry and reflectivities; everything about the run itself lives elsewhere."""

    vertices: tuple[tuple[float, float], ...]
    """Room polygon corners, metres."""
    wall_reflection: tuple[float, ...]
    """Pressure reflection coefficient of each wall (wall i: vertex i -> i+1), 0..1."""
    sensor: tuple[float, float]
    """Co-located speaker and microphone, metres."""
    fan_centre: tuple[float, float]
    """Fan hub centre, metres."""
    blade_length_m: float = 0.58
    hub_radius_m: float = 0.0
    blades: int | None = None
    start_angle_rad: float = 0.0
    blade_reflectivity: float = 1.0
    coupling_gain: float = 1.0
    """Speaker-to-microphone gain of the direct coupling (the pulse's leading edge)."""
    schedule: str | None = None
    """Optional rotation schedule DIR:RATE_HZ:SECONDS,... stated by the scene file."""
    name: str = "scene"
    source: str | None = None
    nuisances: _nuisances.Nuisances | None = None
    """What a real device and room add (sim/nuisances.py), stated by the scene file."""

    # ------------------------------------------------------------------ derived arrays
    @property
    def K(self) -> int:
        return int(self.blades) if self.blades is not None else DEFAULT_BLADES

    @property
    def wall_a(self) -> np.ndarray:
        return np.asarray(self.vertices, dtype=np.float64)

    @property
    def wall_b(self) -> np.ndarray:
        return np.roll(self.wall_a, -1, axis=0)

    @property
    def wall_normals(self) -> np.ndarray:
        """Unit normals pointing into the room, (W, 2)."""
        d = self.wall_b - self.wall_a
        ln = np.hypot(d[:, 0], d[:, 1])[:, None]
        left = np.stack([-d[:, 1], d[:, 0]], axis=1) / ln
        normals: np.ndarray = left if _signed_area(self.wall_a) > 0 else -left
        return normals

    @property
    def tip_radius_m(self) -> float:
        return self.hub_radius_m + self.blade_length_m

    @property
    def sensor_fan_distance_m(self) -> float:
        return math.dist(self.sensor, self.fan_centre)

    def with_config(self, cfg: Config) -> Scene:
        """The scene with its blade count settled against ``cfg.scene.blades``."""
        return settle_blades(self, cfg)

    def describe(self) -> dict[str, Any]:
        """Plain data for truth files."""
        return dict(name=self.name, source=self.source,
                    vertices=[list(v) for v in self.vertices],
                    wall_reflection=list(self.wall_reflection), sensor=list(self.sensor),
                    fan_centre=list(self.fan_centre), blades=self.K,
                    blade_length_m=self.blade_length_m, hub_radius_m=self.hub_radius_m,
                    start_angle_rad=self.start_angle_rad,
                    blade_reflectivity=self.blade_reflectivity,
                    coupling_gain=self.coupling_gain, schedule=self.schedule,
                    nuisances=None if self.nuisances is None else self.nuisances.active)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_mapping(cls, data: Any, *, source: str | None = None,
                     lines: Mapping[str, int] | None = None) -> Scene:
        """Validate a parsed scene document (see config/scenes/paper-room.yaml): its keys
        and numbers by the schema (:class:`SceneFile`), then the floor plan."""
        lines = lines or {}

        def fail(key: str, value: Any, allowed: str) -> NoReturn:
            raise ConfigError(key, value, allowed, source=source, line=lines.get(key))

        doc = _read_document(data, source, lines, fail)
        room, fan = doc.room, doc.fan
        V = _room_polygon(room.vertices, fail)
        refl = _wall_reflections(room.reflection, len(V), fail)
        if not _is_point(doc.sensor):
            fail("sensor", doc.sensor, "must be an [x, y] point in metres")
        centre = fan.centre if "centre" in data["fan"] else fan.center
        if not _is_point(centre):
            fail("fan.centre", centre, "must be an [x, y] point in metres")
        nz = None
        if doc.nuisances is not None:
            nz = _nuisances.parse(doc.nuisances, source=source, lines=lines)
        sched = None
        if doc.schedule is not None:
            sched = _schedule.parse(doc.schedule, key="schedule", source=source).to_string()
        S, C = np.asarray(doc.sensor, float), np.asarray(centre, float)
        _check_placement(S, C, V, fan, doc.sensor, centre, fail)
        return cls(vertices=tuple((float(x), float(y)) for x, y in V),
                   wall_reflection=refl,
                   sensor=(float(S[0]), float(S[1])), fan_centre=(float(C[0]), float(C[1])),
                   blade_length_m=fan.blade_length_m, hub_radius_m=fan.hub_radius_m,
                   blades=fan.blades, start_angle_rad=math.radians(fan.start_angle_deg),
                   blade_reflectivity=fan.reflectivity, coupling_gain=doc.coupling_gain,
                   schedule=sched, nuisances=nz, name=str(doc.name), source=source)


# ---------------------------------------------------------------------- the file's schema

@dataclass(frozen=True)
class RoomFile:
    """A scene file's ``room:``."""

    vertices: Any = opt(None, "room polygon corners [[x, y], ...] in order around the "
                        "room, without closing it", unit="m", nullable=True)
    reflection: Any = opt(0.5, "pressure reflection coefficient of every wall (0 to 1), or "
                          "a list of one per wall (wall i: vertex i -> i+1)", nullable=True)


@dataclass(frozen=True)
class FanFile:
    """A scene file's ``fan:``."""

    centre: Any = opt(None, "fan hub centre [x, y]", unit="m", nullable=True)
    center: Any = opt(None, "the same as centre", unit="m", nullable=True)
    blades: int | None = opt(None, "blade count; must equal the config's scene.blades",
                             lo=1, hi=16, nullable=True,
                             note="or left out to use the config's scene.blades")
    blade_length_m: float = opt(0.58, "blade length from the hub", lo=0.0, hi=100.0,
                                lo_open=True)
    hub_radius_m: float = opt(0.0, "where the blades start, from the centre", lo=0.0,
                              hi=100.0)
    start_angle_deg: float = opt(0.0, "fan angle at time 0 (blade 0 from +x, ccw)",
                                 lo=-1e6, hi=1e6)
    reflectivity: float = opt(1.0, "blade reflection coefficient", lo=0.0, hi=1.0)


@dataclass(frozen=True)
class SceneFile:
    """A scene file as written, every key and number checked (io/scene_file.py reads it;
    :meth:`Scene.from_mapping` checks the floor plan and builds the scene)."""

    name: Any = opt("scene", "the scene's name in truth files and reports", nullable=True)
    description: Any = opt(None, "free text", nullable=True)
    room: RoomFile = field(default_factory=RoomFile)
    sensor: Any = opt(None, "co-located speaker and microphone [x, y]", unit="m",
                      nullable=True)
    fan: FanFile = field(default_factory=FanFile)
    coupling_gain: float = opt(1.0, "speaker-to-microphone gain of the direct coupling",
                               lo=0.0, hi=1e3)
    schedule: Any = opt(None, "rotation schedule DIR:RATE_HZ:SECONDS,... (sim/schedule.py)",
                        nullable=True)
    nuisances: Any = opt(None, "what a real device and room add (sim/nuisances.py)",
                         nullable=True)


def _read_document(data: Any, source: str | None, lines: Mapping[str, int],
                   fail: Callable[[str, Any, str], NoReturn]) -> SceneFile:
    """The document's keys and numbers checked by the schema; room, sensor and fan
    required."""
    if not isinstance(data, Mapping):
        fail("<scene>", data, "must be a mapping with room, sensor and fan")
    schema.check_keys(data, schema.fields_of(SceneFile), "", lines, source)
    for req in ("room", "sensor", "fan"):
        if req not in data:
            fail(req, None, "is required (a scene needs room, sensor and fan; see "
                 "config/scenes/paper-room.yaml)")
    if not isinstance(data["room"], Mapping):
        fail("room", data["room"], "must be a mapping with vertices and reflection")
    if not isinstance(data["fan"], Mapping):
        fail("fan", data["fan"], "must be a mapping with centre, blade_length_m, ...")
    doc: SceneFile = schema.build(SceneFile, data, "", lines, source)
    return doc


def _room_polygon(verts: Any, fail: Callable[[str, Any, str], NoReturn]) -> np.ndarray:
    """``room.vertices`` as an (n, 2) array: 3 to MAX_WALLS corners of a simple polygon
    with an area."""
    if (not isinstance(verts, (list, tuple)) or not 3 <= len(verts) <= MAX_WALLS
            or not all(_is_point(v) for v in verts)):
        fail("room.vertices", verts, f"must be a list of 3 to {MAX_WALLS} [x, y] points "
             "in metres, e.g. [[0, 0], [4, 0], [4, 3], [0, 3]]")
    V = np.asarray(verts, dtype=np.float64)
    seg = np.hypot(*(np.roll(V, -1, axis=0) - V).T)
    if np.any(seg < 1e-6):
        fail("room.vertices", verts, "has a zero-length wall (repeated vertex); "
             "list each corner once, without closing the polygon")
    if abs(_signed_area(V)) < 1e-6:
        fail("room.vertices", verts, "encloses no area")
    if _self_intersects(V):
        fail("room.vertices", verts, "walls cross each other; list the corners in "
             "order around the room")
    return V


def _wall_reflections(refl: Any, nw: int,
                      fail: Callable[[str, Any, str], NoReturn]) -> tuple[float, ...]:
    """``room.reflection``: one number for every wall, or one per wall, each 0 to 1."""
    given = refl
    if _is_num(refl):
        refl = [float(refl)] * nw
    if (not isinstance(refl, (list, tuple)) or len(refl) != nw
            or not all(_is_num(r) and 0.0 <= float(r) <= 1.0 for r in refl)):
        fail("room.reflection", given, f"must be a number from 0 to 1 or "
             f"a list of {nw} such numbers, one per wall (wall i: vertex i -> i+1)")
    return tuple(float(r) for r in refl)


def _check_placement(S: np.ndarray, C: np.ndarray, V: np.ndarray, fan: FanFile,
                     sensor: Any, centre: Any,
                     fail: Callable[[str, Any, str], NoReturn]) -> None:
    """The sensor strictly inside the room, the fan's centre inside and its blade tips
    clear of every wall."""
    if not _inside(S, V) or _dist_to_walls(S, V).min() < MIN_WALL_CLEARANCE_M:
        fail("sensor", sensor, "is not inside the room; put it strictly inside the "
             f"polygon room.vertices (at least {MIN_WALL_CLEARANCE_M * 1000:g} mm from "
             "every wall)")
    if not _inside(C, V):
        fail("fan.centre", centre, "is not inside the room; put it inside room.vertices")
    clear = _dist_to_walls(C, V).min()
    hub, length = fan.hub_radius_m, fan.blade_length_m
    if clear <= hub + length:
        fail("fan.blade_length_m", length, f"blade tips ({hub + length:g} m from the "
             f"centre) would reach a wall ({clear:.3f} m away); shorten the blades or "
             "move fan.centre")


# ---------------------------------------------------------------------- helpers

def _is_num(v: Any) -> bool:
    return (isinstance(v, (int, float)) and not isinstance(v, bool)
            and math.isfinite(float(v)))


def _is_point(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and len(v) == 2 and all(_is_num(c) for c in v)


def _signed_area(V: np.ndarray) -> float:
    x, y = V[:, 0], V[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _inside(p: np.ndarray, V: np.ndarray) -> bool:
    """Even-odd ray casting."""
    x, y = p
    inside = False
    for (x1, y1), (x2, y2) in zip(V, np.roll(V, -1, axis=0), strict=True):
        if (y1 > y) != (y2 > y):
            xc = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
            if xc > x:
                inside = not inside
    return inside


def _dist_to_walls(p: np.ndarray, V: np.ndarray) -> np.ndarray:
    A, B = V, np.roll(V, -1, axis=0)
    d = B - A
    t = np.clip(np.sum((p - A) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-300), 0, 1)
    q = A + t[:, None] * d
    dist: np.ndarray = np.hypot(*(p - q).T)
    return dist


def _self_intersects(V: np.ndarray) -> bool:
    n = len(V)
    A, B = V, np.roll(V, -1, axis=0)
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue
            if _segments_cross(A[i], B[i], A[j], B[j]):
                return True
    return False


def _segments_cross(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> bool:
    def orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
        area: float = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        return area

    d1, d2 = orient(q1, q2, p1), orient(q1, q2, p2)
    d3, d4 = orient(p1, p2, q1), orient(p1, p2, q2)
    if d1 == d2 == d3 == d4 == 0:  # collinear: cross only if the spans overlap
        ax = 0 if abs(p2[0] - p1[0]) >= abs(p2[1] - p1[1]) else 1
        lo1, hi1 = sorted((p1[ax], p2[ax]))
        lo2, hi2 = sorted((q1[ax], q2[ax]))
        return bool(max(lo1, lo2) <= min(hi1, hi2))
    return bool(d1 * d2 <= 0 and d3 * d4 <= 0)


class _BladedScene(Protocol):
    """What :func:`settle_blades` reads of a scene (Scene or Scene3D), a dataclass."""

    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[Any]]]

    @property
    def blades(self) -> int | None: ...

    @property
    def source(self) -> str | None: ...


_SceneT = TypeVar("_SceneT", bound=_BladedScene)


def settle_blades(scene: _SceneT, cfg: Config) -> _SceneT:
    """A scene (2-D or 3-D: a dataclass with ``blades`` and ``source``) with its blade
    count settled against ``cfg.scene.blades``: taken from the config when the scene
    leaves it open, refused when the two disagree."""
    k = cfg.scene.blades
    if scene.blades is None:
        return dataclasses.replace(scene, blades=int(k))
    if int(scene.blades) != int(k):
        raise ConfigError("fan.blades", scene.blades,
                          f"disagrees with the config's scene.blades = {k}; set both to "
                          "the real blade count (the analysis divides the blade-phase "
                          "rate by it)", source=scene.source)
    return scene
