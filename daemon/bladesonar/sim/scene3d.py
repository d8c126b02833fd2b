"""A 3-D scene: a box room, a sensor and a ceiling fan with pitched plate blades (pure).

Conventions (contracts for truth files and the airflow tests):

- Coordinates in metres: x, y the floor plan as drawn (x right, y up, seen from above),
  z up; the floor is z = 0, the ceiling z = ``size[2]``.
- Surfaces (reflection coefficients in this order): 0 the wall x = 0, 1 x = size[0],
  2 y = 0, 3 y = size[1], 4 the floor, 5 the ceiling.
- Rotation is **seen from below** (a person under the fan looking up): fan angle 0 puts
  blade 0 along +x; positive angles and rates are counter-clockwise seen from below, which
  turns +x towards -y (clockwise in the floor plan seen from above). A schedule's
  ``ccw``/``cw`` are therefore seen from below in a 3-D scene.
- A blade is a flat rectangular plate from ``hub_radius_m`` to the tip along its radial
  axis, ``chord_m`` wide, centred on the blade plane's height (the fan centre's z),
  drooped by ``droop_deg`` (tips lower) and pitched by ``pitch_deg`` about its radial axis.
- **Pitch and airflow**: positive ``pitch_deg`` raises the edge that leads when the fan
  turns ccw seen from below. A blade moving with its leading edge high pushes air down, so
  a fan with positive pitch blows **down** turning ccw and **up** turning cw; negative
  pitch is a fan built the other way round. Most ceiling fans blow down turning ccw seen
  from below (the analysis's ``scene.downdraft_rotation`` convention, default ccw).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np

from .. import schema
from ..errors import ConfigError
from ..schema import opt
from . import nuisances as _nuisances
from . import schedule as _schedule
from .scene import DEFAULT_BLADES, settle_blades

if TYPE_CHECKING:
    from ..config import Config

SURFACES = ("wall_x0", "wall_x1", "wall_y0", "wall_y1", "floor", "ceiling")
#: The sensor and the fan centre must sit at least this far inside every surface.
MIN_CLEARANCE_M = 1e-3


@dataclass(frozen=True)
class Scene3D:
    """A box room, a co-located speaker and microphone, and a fan of pitched plates."""

    size: tuple[float, float, float]
    """Room box x, y, z extents, metres (floor at z = 0)."""
    surface_reflection: tuple[float, ...]
    """Pressure reflection coefficient of each surface (order: ``SURFACES``), 0..1."""
    sensor: tuple[float, float, float]
    fan_centre: tuple[float, float, float]
    """Hub centre: x, y of the axis and z of the blade plane, metres."""
    blade_length_m: float = 0.55
    hub_radius_m: float = 0.12
    chord_m: float = 0.12
    pitch_deg: float = 12.0
    """Signed pitch: + raises the edge leading for ccw-from-below rotation (module doc)."""
    droop_deg: float = 0.0
    blades: int | None = None
    start_angle_rad: float = 0.0
    blade_reflectivity: float = 1.0
    lobe_wavelength_m: float = 0.05
    """Wavelength that sets the specular lobe's width: lambda / (2 * plate size) radians
    (standard deviation of a Gaussian lobe) along each side of the plate."""
    diffuse: float = 0.05
    """Amplitude of the diffuse echo from the plate's centre relative to its specular peak."""
    coupling_gain: float = 1.0
    schedule: str | None = None
    name: str = "scene"
    source: str | None = None
    nuisances: _nuisances.Nuisances | None = None

    dims = 3

    @property
    def K(self) -> int:
        return int(self.blades) if self.blades is not None else DEFAULT_BLADES

    @property
    def tip_radius_m(self) -> float:
        return self.hub_radius_m + self.blade_length_m

    @property
    def sensor_fan_distance_m(self) -> float:
        return math.dist(self.sensor, self.fan_centre)

    @property
    def axis_offset_m(self) -> float:
        """Horizontal distance of the sensor from the fan's axis, m."""
        return math.hypot(self.sensor[0] - self.fan_centre[0],
                          self.sensor[1] - self.fan_centre[1])

    @property
    def wall_reflection(self) -> tuple[float, ...]:
        return self.surface_reflection

    def airflow(self, rate_hz: np.ndarray) -> np.ndarray:
        """'down', 'up' or 'none' (at rest or flat blades) at each signed rate (ccw from
        below positive)."""
        s = np.sign(np.asarray(rate_hz, dtype=np.float64)) * np.sign(self.pitch_deg)
        return np.where(s > 0, "down", np.where(s < 0, "up", "none"))

    def room_key(self) -> list[Any]:
        """What seeds the room's late reverberation (sim/render.py)."""
        return [list(self.size), list(self.surface_reflection), list(self.sensor),
                list(self.fan_centre)]

    def with_config(self, cfg: Config) -> Scene3D:
        """The scene with its blade count settled against ``cfg.scene.blades``."""
        return settle_blades(self, cfg)

    def describe(self) -> dict[str, Any]:
        """Plain data for truth files."""
        return dict(name=self.name, source=self.source, dims=3, size=list(self.size),
                    surfaces=list(SURFACES), surface_reflection=list(self.surface_reflection),
                    sensor=list(self.sensor), fan_centre=list(self.fan_centre),
                    axis_offset_m=self.axis_offset_m, blades=self.K,
                    blade_length_m=self.blade_length_m, hub_radius_m=self.hub_radius_m,
                    chord_m=self.chord_m, pitch_deg=self.pitch_deg, droop_deg=self.droop_deg,
                    start_angle_rad=self.start_angle_rad,
                    blade_reflectivity=self.blade_reflectivity,
                    lobe_wavelength_m=self.lobe_wavelength_m, diffuse=self.diffuse,
                    coupling_gain=self.coupling_gain, schedule=self.schedule,
                    nuisances=None if self.nuisances is None else self.nuisances.active)

    @classmethod
    def from_mapping(cls, data: Any, *, source: str | None = None,
                     lines: Mapping[str, int] | None = None) -> Scene3D:
        """Validate a parsed 3-D scene document (config/scenes/living-room-3d.yaml)."""
        lines = lines or {}

        def fail(key: str, value: Any, allowed: str) -> NoReturn:
            raise ConfigError(key, value, allowed, source=source, line=lines.get(key))

        if not isinstance(data, Mapping):
            fail("<scene>", data, "must be a mapping with room, sensor and fan")
        schema.check_keys(data, schema.fields_of(Scene3File), "", lines, source)
        for req in ("room", "sensor", "fan"):
            if req not in data:
                fail(req, None, "is required (a 3-D scene needs room, sensor and fan; see "
                     "config/scenes/living-room-3d.yaml)")
        for sec in ("room", "fan"):
            if not isinstance(data[sec], Mapping):
                fail(sec, data[sec], "must be a mapping (see config/scenes/living-room-3d.yaml)")
        doc: Scene3File = schema.build(Scene3File, data, "", lines, source)
        room, fan = doc.room, doc.fan
        size = room.size
        if not _is_point3(size) or min(size) <= 0.5 or max(size) > 100:
            fail("room.size", size, "must be the box's [x, y, z] extents in metres, each "
                 "above 0.5 and at most 100, e.g. [5.0, 4.0, 2.7]")
        refl = _reflections(room.reflection, fail)
        if not _is_point3(doc.sensor):
            fail("sensor", doc.sensor, "must be an [x, y, z] point in metres")
        centre = fan.centre if "centre" in data["fan"] else fan.center
        if not _is_point3(centre):
            fail("fan.centre", centre, "must be an [x, y, z] point in metres (z: the "
                 "blade plane's height)")
        nz = None
        if doc.nuisances is not None:
            nz = _nuisances.parse(doc.nuisances, source=source, lines=lines)
            if nz.walker_speed_m_s > 0:
                fail("nuisances.walker_speed_m_s", nz.walker_speed_m_s,
                     "is not simulated in a 3-D scene; set it to 0 or use a 2-D scene")
        sched = None
        if doc.schedule is not None:
            sched = _schedule.parse(doc.schedule, key="schedule", source=source).to_string()
        S = tuple(float(v) for v in doc.sensor)
        C = tuple(float(v) for v in centre)
        sz = tuple(float(v) for v in size)
        _check_placement(sz, S, C, fan, doc.sensor, centre, fail)
        return cls(size=(sz[0], sz[1], sz[2]), surface_reflection=refl,
                   sensor=(S[0], S[1], S[2]), fan_centre=(C[0], C[1], C[2]),
                   blade_length_m=fan.blade_length_m, hub_radius_m=fan.hub_radius_m,
                   chord_m=fan.chord_m, pitch_deg=fan.pitch_deg, droop_deg=fan.droop_deg,
                   blades=fan.blades, start_angle_rad=math.radians(fan.start_angle_deg),
                   blade_reflectivity=fan.reflectivity,
                   lobe_wavelength_m=fan.lobe_wavelength_m, diffuse=fan.diffuse,
                   coupling_gain=doc.coupling_gain, schedule=sched, nuisances=nz,
                   name=str(doc.name), source=source)


def is_3d_document(data: Any) -> bool:
    """Whether a parsed scene document describes a 3-D box room (``room.size``)."""
    return (isinstance(data, Mapping) and isinstance(data.get("room"), Mapping)
            and "size" in data["room"])


# ---------------------------------------------------------------------- the file's schema

@dataclass(frozen=True)
class Room3File:
    """A 3-D scene file's ``room:``."""

    size: Any = opt(None, "box extents [x, y, z]; floor at z = 0", unit="m", nullable=True)
    reflection: Any = opt(0.5, "pressure reflection coefficient (0 to 1) of every surface, "
                          "a list of six (x=0, x=max, y=0, y=max, floor, ceiling) or a "
                          "mapping {walls, floor, ceiling}", nullable=True)


@dataclass(frozen=True)
class Fan3File:
    """A 3-D scene file's ``fan:``."""

    centre: Any = opt(None, "fan hub centre [x, y, z], z the blade plane's height",
                      unit="m", nullable=True)
    center: Any = opt(None, "the same as centre", unit="m", nullable=True)
    blades: int | None = opt(None, "blade count; must equal the config's scene.blades",
                             lo=1, hi=16, nullable=True)
    blade_length_m: float = opt(0.55, "blade length from the hub", lo=0.0, hi=5.0,
                                lo_open=True)
    hub_radius_m: float = opt(0.12, "where the blades start, from the axis", lo=0.0,
                              hi=2.0)
    chord_m: float = opt(0.12, "blade width", lo=0.01, hi=1.0)
    pitch_deg: float = opt(12.0, "blade pitch; + raises the edge leading for "
                           "ccw-from-below rotation (a down-draft turning ccw)", lo=-45.0,
                           hi=45.0)
    droop_deg: float = opt(0.0, "blade droop, tips lower", lo=-20.0, hi=20.0)
    start_angle_deg: float = opt(0.0, "fan angle at time 0 (blade 0 from +x, ccw seen "
                                 "from below)", lo=-1e6, hi=1e6)
    reflectivity: float = opt(1.0, "blade reflection coefficient", lo=0.0, hi=1.0)
    lobe_wavelength_m: float = opt(0.05, "wavelength setting the specular lobe's width "
                                   "(lambda / (2 size) rad per side of the plate)",
                                   lo=0.001, hi=1.0)
    diffuse: float = opt(0.05, "diffuse echo relative to the specular peak", lo=0.0, hi=1.0)


@dataclass(frozen=True)
class Scene3File:
    """A 3-D scene file as written (:meth:`Scene3D.from_mapping` checks the placement)."""

    name: Any = opt("scene", "the scene's name in truth files and reports", nullable=True)
    description: Any = opt(None, "free text", nullable=True)
    room: Room3File = field(default_factory=Room3File)
    sensor: Any = opt(None, "co-located speaker and microphone [x, y, z]", unit="m",
                      nullable=True)
    fan: Fan3File = field(default_factory=Fan3File)
    coupling_gain: float = opt(1.0, "speaker-to-microphone gain of the direct coupling",
                               lo=0.0, hi=1e3)
    schedule: Any = opt(None, "rotation schedule DIR:RATE_HZ:SECONDS,... (DIR seen from "
                        "below)", nullable=True)
    nuisances: Any = opt(None, "what a real device and room add (sim/nuisances.py)",
                         nullable=True)


def _reflections(refl: Any, fail: Callable[[str, Any, str], NoReturn]) -> tuple[float, ...]:
    given = refl
    if isinstance(refl, Mapping):
        extra = set(refl) - {"walls", "floor", "ceiling"}
        if extra:
            fail("room.reflection", given, "as a mapping takes the keys walls, floor and "
                 f"ceiling (not {', '.join(sorted(map(str, extra)))})")
        w, f, c = (refl.get(k, 0.5) for k in ("walls", "floor", "ceiling"))
        refl = [w, w, w, w, f, c]
    elif _is_num(refl):
        refl = [refl] * 6
    if (not isinstance(refl, (list, tuple)) or len(refl) != 6
            or not all(_is_num(r) and 0.0 <= float(r) <= 1.0 for r in refl)):
        fail("room.reflection", given, "must be a number from 0 to 1, a list of six such "
             "numbers (x=0, x=max, y=0, y=max, floor, ceiling) or {walls, floor, ceiling}")
    return tuple(float(r) for r in refl)


def _check_placement(size: tuple[float, ...], S: tuple[float, ...], C: tuple[float, ...],
                     fan: Fan3File, sensor: Any, centre: Any,
                     fail: Callable[[str, Any, str], NoReturn]) -> None:
    """Sensor and hub inside the box, blades clear of the walls, floor and ceiling, the
    sensor outside the volume the blades sweep."""
    inside = all(MIN_CLEARANCE_M <= S[i] <= size[i] - MIN_CLEARANCE_M for i in range(3))
    if not inside:
        fail("sensor", sensor, f"is not inside the room; put it inside room.size "
             f"{list(size)} (at least 1 mm from every surface)")
    if not all(MIN_CLEARANCE_M <= C[i] <= size[i] - MIN_CLEARANCE_M for i in range(3)):
        fail("fan.centre", centre, f"is not inside the room; put it inside room.size "
             f"{list(size)}")
    tip = fan.hub_radius_m + fan.blade_length_m
    clear = min(C[0], size[0] - C[0], C[1], size[1] - C[1])
    if clear <= tip:
        fail("fan.blade_length_m", fan.blade_length_m, f"blade tips ({tip:g} m from the "
             f"axis) would reach a wall ({clear:.3f} m away); shorten the blades or move "
             "fan.centre")
    half = _half_height(fan)
    if C[2] + half >= size[2] or C[2] - half <= 0:
        fail("fan.centre", centre, f"blades reach {half:.3f} m above and below the blade "
             f"plane: they would touch the ceiling or the floor; lower or raise fan.centre")
    off = math.hypot(S[0] - C[0], S[1] - C[1])
    if off <= tip + 0.05 and abs(S[2] - C[2]) <= half + 0.05:
        fail("sensor", sensor, "is inside the volume the blades sweep; move it at least "
             "5 cm clear of the blades")


def _half_height(fan: Fan3File) -> float:
    """How far a blade reaches above or below the blade plane, m."""
    tip = fan.hub_radius_m + fan.blade_length_m
    return (0.5 * fan.chord_m * abs(math.sin(math.radians(fan.pitch_deg)))
            + tip * abs(math.sin(math.radians(fan.droop_deg))))


def _is_num(v: Any) -> bool:
    return (isinstance(v, (int, float)) and not isinstance(v, bool)
            and math.isfinite(float(v)))


def _is_point3(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and len(v) == 3 and all(_is_num(c) for c in v)
