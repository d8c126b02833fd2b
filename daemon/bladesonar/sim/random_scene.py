"""Random scenes for sweeps: rooms, sensor places, fans and devices the tuning never saw
(pure).

A scene is drawn from its seed alone, so a seed names the same room, fan, device and day
everywhere (``tools/bench_day --random-scenes``). Seeds are split once and for all into a
tuning set and a held-out set (:func:`split_of`): tuning decisions may look at the first,
never at the second, whose figures are the ones reported.

What is drawn (2-D floor plans, sim/scene.py; the ceiling height is drawn for the 3-D
scenes to come and only sets how far the late reverberation carries):

- a rectangular or L-shaped room, 3-7 m on a side, each wall reflecting 0.2-0.9 of the
  pressure (a curtain to bare plaster), optionally a reverberant tail (RT60 0.2-0.8 s);
- a fan of 3-6 blades, 0.4-0.75 m long, anywhere with its tips 0.3 m clear of the walls;
- the sensor anywhere 0.25 m inside the walls, 0.5 m clear of the blade tips (a floor
  plan has no height: in a room the blades pass a metre or more above the device, and a
  blade 0.15 m from the microphone clips it) and at most 4 m from the hub (beyond about
  5 m the echoes fold into the next pulse), optionally behind a phone's small speaker;
- the fan's speeds: a range [lo, hi] within 0.1-2 Hz (hi at most 3.5 lo), the reference
  taken at a speed inside it (a few per cent off any rate at which a 20 s reference
  shows only a few blade angles, as ``reference`` advises);
- the speaker-to-microphone coupling 1-8 times what a reflector 1 m away returns (the
  paper room's 1 to a phone's clipped coupling, 4 times full scale);
- SNR 6-30 dB, capture clock drift -150..+150 ppm.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..dsp import aliasing
from .nuisances import Nuisances
from .scene import Scene
from .scene3d import Scene3D
from .schedule import ordinary_use

if TYPE_CHECKING:
    from collections.abc import Callable

#: Seeds from this one on are held out: no tuning decision may look at them.
HELD_OUT_FROM = 100_000
#: The first seed of each set (tools/bench_day --random-scenes N takes N from there).
FIRST_SEED = {"tuning": 1, "held-out": HELD_OUT_FROM + 1}
#: Seconds of the reference recording (as bench_day's and the daemon's learning).
REFERENCE_S = 20.0

SIDE_M = (3.0, 7.0)
CEILING_M = (2.4, 3.2)
REFLECTION = (0.2, 0.9)
BLADES = (3, 6)
BLADE_M = (0.4, 0.75)
RATE_HZ = (0.1, 2.0)
SPAN = 3.5
SNR_DB = (6.0, 30.0)
DRIFT_PPM = 150.0
MAX_RANGE_M = 4.0
TIP_CLEARANCE_M = 0.5
#: The least a user moves the device when asked for a place nearer the fan (:func:`nearer`).
MOVE_LEAST_M = 0.5
COUPLING = (1.0, 8.0)


def split_of(seed: int) -> str:
    """'tuning' or 'held-out'."""
    return "held-out" if seed >= HELD_OUT_FROM else "tuning"


@dataclass(frozen=True)
class SceneDraw:
    """One random scene and the day lived in it."""

    seed: int
    scene: Scene
    blades: int
    snr_db: float
    drift_ppm: float
    rates_hz: tuple[float, float]
    ref_rate_hz: float
    ref_direction: str
    ceiling_m: float
    nuisances: Nuisances = field(default_factory=Nuisances)
    moved_from: tuple[tuple[float, float], ...] = ()
    """The places the device stood before (:func:`moved`), first to last."""

    @property
    def split(self) -> str:
        return split_of(self.seed)

    def schedule(self, seconds: float) -> str:
        """The day: ordinary use at this fan's speeds, starting at the reference's."""
        rng = np.random.default_rng([self.seed, 2])
        return ordinary_use(rng, seconds, rates=self.rates_hz,
                            first=(self.ref_direction, round(self.ref_rate_hz, 3)))

    def describe(self) -> dict[str, Any]:
        s = self.scene
        return {"seed": self.seed, "split": self.split,
                "room": [[round(x, 3), round(y, 3)] for x, y in s.vertices],
                "reflection": [round(r, 2) for r in s.wall_reflection],
                "sensor": [round(c, 2) for c in s.sensor],
                "fan_centre": [round(c, 2) for c in s.fan_centre], "blades": self.blades,
                "blade_length_m": round(s.blade_length_m, 2),
                "sensor_fan_m": round(s.sensor_fan_distance_m, 2),
                "ceiling_m": round(self.ceiling_m, 2),
                "coupling_gain": round(s.coupling_gain, 2), "snr_db": round(self.snr_db, 1),
                "drift_ppm": round(self.drift_ppm, 1),
                "rates_hz": [round(r, 3) for r in self.rates_hz],
                "reference": f"{self.ref_direction}:{self.ref_rate_hz:.3f}",
                "nuisances": self.nuisances.active,
                **({"moved_from": [[round(c, 2) for c in p] for p in self.moved_from]}
                   if self.moved_from else {})}


def moved(dr: SceneDraw, attempt: int = 0) -> SceneDraw:
    """The day of ``dr`` with the device put where ``reference`` asks when the place
    tells the fan's directions apart too weakly (``direction_contrast`` under
    ``reference_build.PLACE_CONTRAST``): nearer a wall and further off the fan's axis, in
    the same room, within the reach and clearances of :func:`draw`. A user does not know
    where the telling echoes are, so the place is drawn (from the seed and ``attempt``)
    among those that follow the advice; when none does, among those that follow half of
    it; when none is in reach at all, ``dr`` as it is."""
    s = dr.scene
    V = np.asarray(s.vertices)
    old = np.asarray(s.sensor)
    centre = np.asarray(s.fan_centre)
    wall, axis = _clearance(old, V), s.sensor_fan_distance_m
    rng = np.random.default_rng([dr.seed, 3, attempt])

    def reach(p: np.ndarray) -> bool:
        return s.tip_radius_m + TIP_CLEARANCE_M <= math.dist(p, centre) <= MAX_RANGE_M

    both = _point(rng, V, 0.25, lambda p: reach(p) and _clearance(p, V) < wall
                  and math.dist(p, centre) > axis)
    place = both if both is not None else _point(
        rng, V, 0.25, lambda p: reach(p) and (_clearance(p, V) < wall
                                             or math.dist(p, centre) > axis))
    return _placed(dr, place)


def nearer(dr: SceneDraw, attempt: int = 0) -> SceneDraw:
    """The day of ``dr`` with the device put where ``reference`` asks when it sees the fan
    too little or in look-alikes (``match_share`` under ``reference_build.MATCH_SHARE``,
    or ``astray_share`` from ``ASTRAY_SHARE``): nearer the fan, or on another side of it,
    in the same room, within the reach and clearances of :func:`draw`. Drawn (from the
    seed and ``attempt``) among the places at most 3/4 of the old distance from the hub
    (or within 0.5 m of the nearest the blades allow), 0.5 m or more from the old place;
    when none is, among all in reach 0.5 m or more away; when none is in reach at all,
    ``dr`` as it is."""
    s = dr.scene
    V = np.asarray(s.vertices)
    old = np.asarray(s.sensor)
    centre = np.asarray(s.fan_centre)
    least = s.tip_radius_m + TIP_CLEARANCE_M
    rng = np.random.default_rng([dr.seed, 5, attempt])

    def reach(p: np.ndarray) -> bool:
        return least <= math.dist(p, centre) <= MAX_RANGE_M \
            and math.dist(p, old) >= MOVE_LEAST_M

    near = max(0.75 * s.sensor_fan_distance_m, least + 0.5)
    place = _point(rng, V, 0.25, lambda p: reach(p) and math.dist(p, centre) <= near)
    if place is None:
        place = _point(rng, V, 0.25, reach)
    return _placed(dr, place)


def _placed(dr: SceneDraw, place: np.ndarray | None) -> SceneDraw:
    """``dr`` with the device at ``place`` and its old place kept in ``moved_from``;
    ``dr`` as it is when there is no place."""
    if place is None:
        return dr
    old = dr.scene.sensor
    return dataclasses.replace(
        dr, scene=dataclasses.replace(dr.scene, sensor=(float(place[0]), float(place[1]))),
        moved_from=(*dr.moved_from, (float(old[0]), float(old[1]))))


def _room(rng: np.random.Generator) -> list[list[float]]:
    w, d = (float(rng.uniform(*SIDE_M)) for _ in range(2))
    if rng.uniform() < 0.3:                      # an L: one corner cut out
        cw, cd = float(rng.uniform(0.25, 0.45)) * w, float(rng.uniform(0.25, 0.45)) * d
        return [[0.0, 0.0], [w, 0.0], [w, d - cd], [w - cw, d - cd], [w - cw, d], [0.0, d]]
    return [[0.0, 0.0], [w, 0.0], [w, d], [0.0, d]]


def _clearance(p: np.ndarray, V: np.ndarray) -> float:
    A, B = V, np.roll(V, -1, axis=0)
    dv = B - A
    t = np.clip(np.sum((p - A) * dv, axis=1) / np.sum(dv * dv, axis=1), 0.0, 1.0)
    return float(np.hypot(*(p - (A + t[:, None] * dv)).T).min())


def _inside(p: np.ndarray, V: np.ndarray) -> bool:
    x, y = p
    inside = False
    for (x1, y1), (x2, y2) in zip(V, np.roll(V, -1, axis=0), strict=True):
        if (y1 > y) != (y2 > y) and x1 + (y - y1) * (x2 - x1) / (y2 - y1) > x:
            inside = not inside
    return inside


def _point(rng: np.random.Generator, V: np.ndarray, clear: float,
           ok: Callable[[np.ndarray], bool] = lambda p: True) -> np.ndarray | None:
    lo, hi = V.min(axis=0), V.max(axis=0)
    for _ in range(500):
        p: np.ndarray = rng.uniform(lo, hi)
        if _inside(p, V) and _clearance(p, V) >= clear and ok(p):
            return p
    return None


def _reference_rate(rng: np.random.Generator, lo: float, hi: float, blades: int,
                    prf: float) -> float:
    """A speed in [lo, hi] whose 20 s reference shows the blade at many angles: off
    every p/q (q <= 12) by two gaps 1/q over the record. Nearer (a 5-blade fan at
    0.681 Hz is 0.10012 blade period per pulse: ten clusters of angles, each 0.088
    wide), the period search cannot tell p/q from 3p/q and picked the wrong one; the
    reference warns near such rates, and the user is told to take another speed."""
    span = int(REFERENCE_S * prf)
    r = float(np.exp(rng.uniform(math.log(lo), math.log(hi))))
    for _ in range(50):
        c = r * blades / prf
        if aliasing.folded_angles(c, span) is None and not any(
                abs(c - round(c * q) / q) * span < 2.0 / q for q in range(1, 13)
                if round(c * q) > 0):
            return r
        r *= 1.03 if r * 1.03 <= hi else 0.97
    return r


def _day_speeds(rng: np.random.Generator, blades: int, prf: float
                ) -> tuple[float, float, float, str]:
    """A day's speed range [lo, hi] within 0.1-2 Hz (hi at most 3.5 lo), the reference's
    speed inside it and its direction."""
    lo = float(np.exp(rng.uniform(math.log(RATE_HZ[0]), math.log(0.6))))
    hi = min(lo * float(rng.uniform(2.0, SPAN)), RATE_HZ[1])
    ref = _reference_rate(rng, lo, hi, blades, prf)
    return lo, hi, ref, "ccw" if rng.uniform() < 0.5 else "cw"


def draw(seed: int, prf: float = 44100.0 / 1297) -> SceneDraw:
    """The scene of ``seed`` (same seed, same scene); ``prf`` the config's, Hz."""
    rng = np.random.default_rng([seed, 1])
    while True:
        verts = _room(rng)
        V = np.asarray(verts)
        K = int(rng.integers(BLADES[0], BLADES[1] + 1))
        length = float(rng.uniform(*BLADE_M))
        hub = float(rng.uniform(0.05, 0.15))
        tip = hub + length
        centre = _point(rng, V, tip + 0.3)
        if centre is None:
            continue

        # a def, not a lambda: mypy cannot infer a lambda with defaults as a Callable
        def in_reach(p: np.ndarray, c: np.ndarray = centre, t: float = tip) -> bool:
            return t + TIP_CLEARANCE_M <= math.dist(p, c) <= MAX_RANGE_M

        sensor = _point(rng, V, 0.25, in_reach)
        if sensor is not None:
            break
    refl = [round(float(rng.uniform(*REFLECTION)), 3) for _ in verts]
    ceiling = float(rng.uniform(*CEILING_M))
    lo, hi, ref, ref_dir = _day_speeds(rng, K, prf)
    coupling = float(np.exp(rng.uniform(0.0, math.log(COUPLING[1]))))
    snr = float(rng.uniform(*SNR_DB))
    drift = float(rng.uniform(-DRIFT_PPM, DRIFT_PPM))
    nz: dict[str, Any] = {}
    if rng.uniform() < 0.5:                      # a reverberant room
        nz["rt60_s"] = round(float(rng.uniform(0.2, 0.8)) * ceiling / 2.8, 3)
        nz["reverb_db"] = round(float(rng.uniform(-12.0, 0.0)), 1)
    if rng.uniform() < 0.5:                      # a phone's small speaker
        nz["speaker_highpass_hz"] = round(float(rng.uniform(300.0, 800.0)), 0)
        nz["speaker_resonance_hz"] = round(float(rng.uniform(1500.0, 4000.0)), 0)
    scene = Scene.from_mapping({
        "name": f"random-{seed}",
        "room": {"vertices": verts, "reflection": refl},
        "sensor": [float(sensor[0]), float(sensor[1])], "coupling_gain": coupling,
        "fan": {"centre": [float(centre[0]), float(centre[1])], "blades": K,
                "blade_length_m": length, "hub_radius_m": hub,
                "start_angle_deg": float(rng.uniform(0.0, 360.0))},
    })
    return SceneDraw(seed=seed, scene=scene, blades=K, snr_db=snr, drift_ppm=drift,
                     rates_hz=(lo, hi), ref_rate_hz=ref, ref_direction=ref_dir,
                     ceiling_m=ceiling, nuisances=Nuisances(**nz))


# ---------------------------------------------------------------------- 3-D scenes

#: What a random 3-D scene draws (sim/scene3d.py), for the airflow sweep (tools/bench_airflow).
AXIS_OFFSET_M = (0.5, 3.0)
SENSOR_Z_M = (0.3, 1.8)
PITCH_DEG = (6.0, 18.0)
RATE3_HZ = (0.15, 1.6)
BLADES3 = (3, 5)
SNR3_DB = (4.0, 20.0)
SECONDS3 = (6.0, 15.0)


@dataclass(frozen=True)
class SceneDraw3D:
    """One random 3-D scene and the run recorded in it."""

    seed: int
    scene: Scene3D
    blades: int
    snr_db: float
    drift_ppm: float
    schedule: str
    seconds: float
    rate_hz: float
    """The steady signed rate after the ramp, ccw seen from below positive."""
    nuisances: Nuisances = field(default_factory=Nuisances)

    @property
    def split(self) -> str:
        return split_of(self.seed)

    @property
    def airflow(self) -> str:
        """'down' or 'up' (the truth once the fan turns)."""
        return str(self.scene.airflow(np.array([self.rate_hz]))[0])

    def describe(self) -> dict[str, Any]:
        s = self.scene
        return {"seed": self.seed, "split": self.split, "size": [round(v, 2) for v in s.size],
                "sensor": [round(v, 2) for v in s.sensor],
                "fan_centre": [round(v, 2) for v in s.fan_centre], "blades": self.blades,
                "blade_length_m": round(s.blade_length_m, 2),
                "axis_offset_m": round(s.axis_offset_m, 2),
                "pitch_deg": round(s.pitch_deg, 1), "droop_deg": round(s.droop_deg, 1),
                "lobe_wavelength_m": round(s.lobe_wavelength_m, 3),
                "rate_hz": round(self.rate_hz, 3), "schedule": self.schedule,
                "seconds": round(self.seconds, 1), "snr_db": round(self.snr_db, 1),
                "drift_ppm": round(self.drift_ppm, 1), "airflow": self.airflow,
                "nuisances": self.nuisances.active}


def draw_3d(seed: int) -> SceneDraw3D:
    """The 3-D scene of ``seed``: a box room 3-7 m by 3-7 m with a 2.4-3.2 m ceiling, a fan
    of 3-5 blades pitched 6-18 degrees either way 0.25-0.6 m below the ceiling, the sensor
    0.3-1.8 m high and 0.5-3 m off the fan's axis, a run of 6-15 s at 0.15-1.6 Hz either
    way (from rest over a ramp of up to 4 s in half the runs), SNR 4-20 dB, drift up to
    +-150 ppm, a reverberant tail, a small speaker, an AGC and bursts in some of them.
    Independent of :func:`draw` (its own random stream)."""
    rng = np.random.default_rng([seed, 3])
    while True:
        lx, ly = (float(rng.uniform(*SIDE_M)) for _ in range(2))
        lz = float(rng.uniform(*CEILING_M))
        K = int(rng.integers(BLADES3[0], BLADES3[1] + 1))
        length = float(rng.uniform(*BLADE_M))
        hub = float(rng.uniform(0.08, 0.15))
        tip = hub + length
        if min(lx, ly) < 2 * (tip + 0.3) + 0.1:
            continue
        cx = float(rng.uniform(tip + 0.3, lx - tip - 0.3))
        cy = float(rng.uniform(tip + 0.3, ly - tip - 0.3))
        cz = lz - float(rng.uniform(0.25, 0.6))
        off = float(rng.uniform(*AXIS_OFFSET_M))
        az = float(rng.uniform(0.0, 2 * math.pi))
        sx, sy = cx + off * math.cos(az), cy + off * math.sin(az)
        if 0.25 <= sx <= lx - 0.25 and 0.25 <= sy <= ly - 0.25:
            break
    sz = float(rng.uniform(SENSOR_Z_M[0], min(SENSOR_Z_M[1], cz - 0.5)))
    refl = [round(float(rng.uniform(*REFLECTION)), 3) for _ in range(6)]
    pitch = float(rng.uniform(*PITCH_DEG)) * (1.0 if rng.uniform() < 0.5 else -1.0)
    rate = float(np.exp(rng.uniform(math.log(RATE3_HZ[0]), math.log(RATE3_HZ[1]))))
    direction = "ccw" if rng.uniform() < 0.5 else "cw"
    seconds = round(float(rng.uniform(*SECONDS3)), 1)
    ramp = round(float(rng.uniform(1.0, 4.0)), 1) if rng.uniform() < 0.5 else 0.0
    schedule = f"{direction}:{rate:.4f}:{seconds:g}" + (f"~{ramp:g}" if ramp else "")
    nz: dict[str, Any] = {}
    if rng.uniform() < 0.5:
        nz["rt60_s"] = round(float(rng.uniform(0.2, 0.8)) * lz / 2.8, 3)
        nz["reverb_db"] = round(float(rng.uniform(-12.0, 0.0)), 1)
    if rng.uniform() < 0.5:
        nz["speaker_highpass_hz"] = round(float(rng.uniform(300.0, 800.0)), 0)
        nz["speaker_resonance_hz"] = round(float(rng.uniform(1500.0, 4000.0)), 0)
    if rng.uniform() < 0.25:
        nz["agc_db"] = round(float(rng.uniform(1.0, 4.0)), 1)
    if rng.uniform() < 0.25:
        nz["burst_fraction"] = round(float(rng.uniform(0.02, 0.1)), 3)
    scene = Scene3D.from_mapping({
        "name": f"random3d-{seed}",
        "room": {"size": [lx, ly, lz], "reflection": refl},
        "sensor": [sx, sy, sz],
        "coupling_gain": float(np.exp(rng.uniform(0.0, math.log(COUPLING[1])))),
        "fan": {"centre": [cx, cy, cz], "blades": K, "blade_length_m": length,
                "hub_radius_m": hub, "chord_m": float(rng.uniform(0.09, 0.15)),
                "pitch_deg": pitch, "droop_deg": float(rng.uniform(0.0, 4.0)),
                "start_angle_deg": float(rng.uniform(0.0, 360.0)),
                "lobe_wavelength_m": float(rng.uniform(0.03, 0.08)),
                "diffuse": float(rng.uniform(0.02, 0.1))},
    })
    return SceneDraw3D(seed=seed, scene=scene, blades=K,
                       snr_db=float(rng.uniform(*SNR3_DB)),
                       drift_ppm=float(rng.uniform(-DRIFT_PPM, DRIFT_PPM)),
                       schedule=schedule, seconds=seconds,
                       rate_hz=rate if direction == "ccw" else -rate, nuisances=Nuisances(**nz))


def reverberant(d: SceneDraw3D) -> SceneDraw3D:
    """``d`` in a reverberant room: RT60 0.45-0.8 s (scaled by the ceiling as in
    :func:`draw_3d`) and the tail -6..0 dB, drawn from the seed (``tools/bench_airflow
    --reverb``: cases built to study the fan's share of the tail)."""
    rng = np.random.default_rng([d.seed, 77])
    nz = dataclasses.replace(
        d.nuisances, rt60_s=round(float(rng.uniform(0.45, 0.8)) * d.scene.size[2] / 2.8, 3),
        reverb_db=round(float(rng.uniform(-6.0, 0.0)), 1))
    return dataclasses.replace(d, nuisances=nz)


@dataclass(frozen=True)
class DayDraw3D:
    """A random 3-D scene (:func:`draw_3d`) and a day of ordinary use lived in it, with
    the same interface as :class:`SceneDraw` (tools/days.py ``random_day``)."""

    seed: int
    room: SceneDraw3D
    snr_db: float
    rates_hz: tuple[float, float]
    ref_rate_hz: float
    ref_direction: str

    dims = 3

    @property
    def split(self) -> str:
        return split_of(self.seed)

    @property
    def scene(self) -> Scene3D:
        return self.room.scene

    @property
    def blades(self) -> int:
        return self.room.blades

    @property
    def drift_ppm(self) -> float:
        return self.room.drift_ppm

    @property
    def nuisances(self) -> Nuisances:
        return self.room.nuisances

    def schedule(self, seconds: float) -> str:
        """The day (ccw/cw seen from below): ordinary use at this fan's speeds, starting
        at the reference's; a stream of its own, apart from the 2-D day's."""
        rng = np.random.default_rng([self.seed, 5])
        return ordinary_use(rng, seconds, rates=self.rates_hz,
                            first=(self.ref_direction, round(self.ref_rate_hz, 3)))

    def describe(self) -> dict[str, Any]:
        r = self.room.describe()
        for k in ("rate_hz", "schedule", "seconds", "airflow"):
            r.pop(k)
        return {**r, "dims": 3, "sensor_fan_m": round(self.scene.sensor_fan_distance_m, 2),
                "coupling_gain": round(self.scene.coupling_gain, 2),
                "snr_db": round(self.snr_db, 1),
                "rates_hz": [round(v, 3) for v in self.rates_hz],
                "reference": f"{self.ref_direction}:{self.ref_rate_hz:.3f}"}


def draw_day_3d(seed: int, prf: float = 44100.0 / 1297) -> DayDraw3D:
    """The 3-D day of ``seed`` (tools/bench_day --dims 3): the room, fan, sensor, drift and
    nuisances of :func:`draw_3d` (AGC and bursts included where drawn), and from a stream
    of their own the day's SNR (6-30 dB, as the 2-D sweep's) and speeds (as :func:`draw`'s:
    a range within 0.1-2 Hz, the reference at a speed inside it). Independent of the 2-D
    scene of the same seed."""
    room = draw_3d(seed)
    rng = np.random.default_rng([seed, 4])
    lo, hi, ref, ref_dir = _day_speeds(rng, room.blades, prf)
    return DayDraw3D(seed=seed, room=room, snr_db=float(rng.uniform(*SNR_DB)),
                     rates_hz=(lo, hi), ref_rate_hz=ref, ref_direction=ref_dir)
