"""Streaming renderer: scene + schedule -> the capture a co-located mic would record (pure).

Time model (all positions in capture samples, fractional, never rounded):

- Pulse k leaves the speaker at playback sample ``offset + k * pri`` (true time
  ``(offset + k * pri) / fs``); the fan is static during a pulse at the schedule's angle
  at that time.
- Every path arrives at ``(offset + k * pri + delay) * (1 + drift_ppm * 1e-6)``: the capture
  clock runs fast by ``drift_ppm``. ``delay = length_m / c * fs``, 0 for the direct coupling,
  so delays and one-way ranges (``c * delay / fs / 2``) count from the coupling edge.
- Each arrival is the configured pulse shape convolved with a band-limited fractional-delay
  impulse (``waveform.kernel``), amplitude ``cfg.waveform.amplitude * gain``; the direct
  coupling therefore peaks at ``amplitude * coupling_gain`` (on the sample grid).

SNR definition: ``snr_db = 10 log10(P_fan / sigma**2)``, where P_fan is the mean square of the
fan echo alone (paths ``blade``, ``wall_blade``, ``blade_wall``; noise-free, nominal clock)
over the samples inside the one-way range gate of every pulse of the run, and sigma is the
standard deviation of the white Gaussian noise added to every sample. Gate:
``cfg.scene.gate_start_m .. gate_stop_m``; null ends default to ``DEFAULT_GATE_START_M`` and
the last unambiguous range (one PRI). P_fan is computed from the path list before
rendering, so streaming needs one pass. If the fan never echoes inside the gate, the
reference falls back to all echoes in the gate, then to the coupling peak power (recorded
as ``snr.reference`` in the truth).

Real devices and rooms (``nuisances``, sim/nuisances.py), each where it happens: the small
speaker's response shapes the transmitted pulse (every path, the coupling too); the late
reverberation (sim/reverb.py) and a walking person (sim/walker.py) are echoes of the room;
interference bursts (sim/device.py) arrive at the microphone with the noise; then the
microphone's gain and AGC wander scale all of it; the converter clips at full scale
(always: a coupling above full scale is clipped there, as on a phone) and quantises. The
room's speed of sound may differ from the config's (``speed_of_sound``): the delays are the
room's, the gate and the truth's delays the config's view.

Drop-outs: runs of capture samples lost. ``mode="remove"`` (default) deletes them, so later
samples shift earlier (what an ALSA overrun does); ``mode="zero"`` zeroes them in place. The
output always has ``round(seconds * fs)`` samples; with removal the capture covers that
many plus the dropped ones. Chunked and one-shot output are bit-identical: geometry comes
from fixed blocks of pulses and noise from fixed, separately seeded blocks of samples.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import waveform
from ..errors import ConfigError
from . import device as _device
from . import geometry
from . import schedule as _schedule
from .nuisances import Nuisances
from .reverb import Tail
from .scene import Scene
from .scene3d import Scene3D
from .walker import walker_paths

if TYPE_CHECKING:
    from ..config import Config

log = logging.getLogger(__name__)

DEFAULT_GATE_START_M = 0.3
DEFAULT_CHUNK_SAMPLES = 1 << 17
_PULSE_BLOCK = 256
_NOISE_BLOCK = 1 << 16
_FULL_SCALE = 32767.0 / 32768.0
TRUTH_FORMAT = "bladesonar-truth/1"


@dataclass(frozen=True)
class Dropout:
    output_index: int
    """First output sample after the gap (remove mode) or first zeroed sample (zero mode)."""
    capture_index: int
    """First lost sample in the uninterrupted capture."""
    samples: int


def echo_response(scene: Scene, cfg: Config, fan_angle_rad: float, n_samples: int, *,
                  include_coupling: bool = True, wall_bounces: bool = True) -> np.ndarray:
    """Band-limited room+fan impulse response over one PRI (or ``n_samples``), float64.

    Sample 0 is the direct coupling (gain ``scene.coupling_gain``); no pulse shape and no
    transmit amplitude: convolve what is played with it. Kernel taps before sample 0 are
    dropped (they matter only for echoes within 16 samples of the coupling).
    """
    scene = scene.with_config(cfg)
    p = geometry_of(scene).paths(scene, fan_angle_rad, wall_bounces=wall_bounces)
    keep = np.ones(len(p.kind), bool) if include_coupling else p.kind != "coupling"
    d = p.delay_samples(cfg.scene.speed_of_sound, cfg.audio.sample_rate)[keep]
    idx, w = waveform.shaped_taps(d, p.gain[keep], np.ones(1))
    return waveform.render(idx, w, 0, int(n_samples))


def geometry_of(scene: Scene | Scene3D) -> Any:
    """The path module of a scene: ``geometry`` (2-D floor plan) or ``geometry3d``."""
    if isinstance(scene, Scene3D):
        from . import geometry3d
        return geometry3d
    return geometry


def gate_samples(cfg: Config) -> tuple[float, float, tuple[float, float]]:
    """The range gate as delays in samples from the coupling edge, and in metres."""
    g0 = cfg.scene.gate_start_m if cfg.scene.gate_start_m is not None else DEFAULT_GATE_START_M
    g1 = cfg.scene.gate_stop_m if cfg.scene.gate_stop_m is not None else cfg.max_range_m
    k = 2.0 * cfg.audio.sample_rate / cfg.scene.speed_of_sound
    return g0 * k, g1 * k, (float(g0), float(g1))


class Simulator:
    """Renders a run in chunks; see the module docstring for the model.

    Parameters
    ----------
    scene, cfg : the scene and the validated config (sample rate, PRI, pulse, c, K).
    schedule : Schedule, "DIR:RATE:SECONDS,..." or list; None: the scene's, else
        ``cfg.sim.schedule``.
    snr_db : fan-echo to noise power in the gate; None: no noise.
    seed : seeds noise, the random start offset and random drop-out positions.
    start_offset : playback sample of pulse 0 in [0, pri); None: uniform random (seeded).
    drift_ppm : capture clock fast by this many parts per million (negative: slow).
    dropouts : number of random drop-outs, or a sequence of (output_index, samples).
    dropout_samples : length of each random drop-out.
    dropout_mode : "remove" (later samples shift earlier) or "zero".
    dc_offset : added to every sample (full scale = 1).
    clip : clip level in (0, 1]; samples beyond are clipped and counted; None: none.
    wall_bounces : False keeps only the direct blade echo (plus coupling and walls).
    include_paths : put each pulse's path list in its truth record.
    nuisances : what a real device and room add (sim/nuisances.py); None: the scene's,
        else none.
    """

    def __init__(self, scene: Scene | Scene3D, cfg: Config, schedule: Any = None, *,
                 snr_db: float | None = None, seed: int = 0,
                 start_offset: float | None = None, drift_ppm: float = 0.0,
                 dropouts: int | Sequence[tuple[int, int]] = 0, dropout_samples: int = 64,
                 dropout_mode: str = "remove", dc_offset: float = 0.0,
                 clip: float | None = None, wall_bounces: bool = True,
                 include_paths: bool = True, nuisances: Nuisances | None = None) -> None:
        self.scene = scene.with_config(cfg)
        self.geo = geometry_of(self.scene)
        self.nz = nuisances if nuisances is not None else (scene.nuisances or Nuisances())
        self.cfg = cfg
        if schedule is None:
            schedule = scene.schedule if scene.schedule is not None else cfg.sim.schedule
        self.schedule = _schedule.parse(schedule, key="schedule")
        self.fs = float(cfg.audio.sample_rate)
        self.pri = int(cfg.waveform.pri_samples)
        #: the room's speed of sound (delays); the config's is what the analysis assumes
        self.c = float(self.nz.speed_of_sound or cfg.scene.speed_of_sound)
        self.c_cfg = float(cfg.scene.speed_of_sound)
        self.amplitude = float(cfg.waveform.amplitude)
        self.speaker = _device.speaker_response(self.nz, self.fs)
        self.shape = np.convolve(waveform.cfg_pulse(cfg), self.speaker)
        self.wall_bounces = bool(wall_bounces)
        self.include_paths = bool(include_paths)
        if snr_db is not None and not (isinstance(snr_db, (int, float)) and math.isfinite(snr_db)
                                       and -60.0 <= snr_db <= 200.0):
            raise ConfigError("snr_db", snr_db, "must be a number from -60 to 200 dB, or "
                              "None / inf for no noise")
        self.snr_db = None if snr_db is None else float(snr_db)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ConfigError("seed", seed, "must be an integer >= 0")
        self.seed = int(seed)
        if start_offset is None:
            start_offset = float(np.random.default_rng([self.seed, 0]).uniform(0, self.pri))
        if not (isinstance(start_offset, (int, float)) and 0 <= start_offset < self.pri):
            raise ConfigError("start_offset", start_offset,
                              f"must be a number of samples from 0 to below pri_samples "
                              f"({self.pri})")
        self.offset = float(start_offset)
        if not (isinstance(drift_ppm, (int, float)) and abs(drift_ppm) <= 10000):
            raise ConfigError("drift_ppm", drift_ppm, "must be a number from -10000 to 10000 "
                              "ppm (real sound cards: within +-100)")
        self.drift_ppm = float(drift_ppm)
        self.scale = 1.0 + self.drift_ppm * 1e-6
        if dropout_mode not in ("remove", "zero"):
            raise ConfigError("dropout_mode", dropout_mode, "must be remove or zero")
        self.dropout_mode = dropout_mode
        if isinstance(dropout_samples, bool) or not isinstance(dropout_samples, int) \
                or dropout_samples < 1:
            raise ConfigError("dropout_samples", dropout_samples, "must be an integer >= 1")
        self._dropout_spec, self.dropout_samples = dropouts, int(dropout_samples)
        if not (isinstance(dc_offset, (int, float)) and abs(dc_offset) <= 1.0):
            raise ConfigError("dc_offset", dc_offset, "must be a number from -1 to 1 "
                              "(full scale = 1)")
        self.dc_offset = float(dc_offset)
        if clip is not None and not (isinstance(clip, (int, float)) and 0 < clip <= 1.0):
            raise ConfigError("clip", clip, "must be a level above 0 up to 1 (full scale), "
                              "or None")
        self.clip = None if clip is None else min(float(clip), _FULL_SCALE)
        self.clipped = 0
        self.K = self.scene.K
        self.alias_limit_hz = self.fs / self.pri / (2 * self.K)
        self._warn_stiff()
        self.meta: dict[str, Any] | None = None
        self._blocks: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._noise_cache: tuple[int, np.ndarray] | None = None
        self._dmax = self._max_delay_samples()
        self._kind = self.geo.path_table(self.scene, np.zeros(1),
                                         wall_bounces=self.wall_bounces).kind
        if isinstance(self.scene, Scene3D) and self.nz.walker_speed_m_s > 0:
            raise ConfigError("walker_speed_m_s", self.nz.walker_speed_m_s,
                              "is not simulated in a 3-D scene; set it to 0 or use a 2-D "
                              "scene")
        self.tail = self._make_tail()
        self.bursts: list[_device.Burst] = []
        self.burst_rms = 0.0
        self._burst_cache: tuple[int, np.ndarray] | None = None

    def _make_tail(self) -> Tail | None:
        """The late reverberation: begins at the earliest second-order echo (twice the
        nearest wall's delay); its whole energy is ``reverb_db`` relative to the
        first-order wall echoes' (the higher orders together: about their energy in a
        lively room)."""
        if self.nz.rt60_s <= 0:
            return None
        p = self.geo.paths(self.scene, 0.0, wall_bounces=False)
        walls = p.kind == "wall"
        if walls.any():
            d = p.delay_samples(self.c, self.fs)[walls]
            e_walls = float(np.sum(p.gain[walls] ** 2))
            start = 2.0 * float(d.min())
        else:
            e_walls, start = 0.01, 0.02 * self.fs
        # mean square envelope 10^(-6 t / RT60) summed over the tail's samples
        samples = self.nz.rt60_s * self.fs / (6.0 * math.log(10.0))
        level = self.amplitude * math.sqrt(e_walls / samples) * 10 ** (self.nz.reverb_db / 20)
        # the tail belongs to the room, not to the run: the same scene rings the same way
        # in a reference and in a later probe (seeded by the geometry, not by --seed)
        if isinstance(self.scene, Scene3D):
            key: list[Any] = self.scene.room_key()
        else:
            key = [self.scene.vertices, self.scene.wall_reflection, self.scene.sensor,
                   self.scene.fan_centre]
        room = json.dumps(key).encode()
        room_seed = int.from_bytes(hashlib.sha256(room).digest()[:4], "little")
        return Tail(self.nz.rt60_s, start, level, self.nz.reverb_fan_share, self.shape,
                    self.fs, room_seed, time_scale=343.0 / self.c)
    # ------------------------------------------------------------------ set-up
    def _warn_stiff(self) -> None:
        top = self.schedule.max_abs_hz
        if top >= self.alias_limit_hz:
            log.warning("rate %.3g Hz reaches the aliasing limit PRF/(2K) = %.3g Hz: the blade "
                        "phase advances half a period or more per pulse, so the analysis "
                        "cannot tell the direction (simulating anyway)", top,
                        self.alias_limit_hz)
        d = self.scene.sensor_fan_distance_m
        if d <= self.scene.hub_radius_m + 1e-9:
            log.warning("sensor is inside the fan hub (%.3g m from the centre): no blade is "
                        "ever at a specular angle for the direct echo", d)

    def _max_delay_samples(self) -> float:
        if isinstance(self.scene, Scene3D):
            return float(self.geo.max_path_m(self.scene)) / self.c * self.fs + 1.0
        s = self.scene
        S, C = np.asarray(s.sensor), np.asarray(s.fan_centre)
        delta = np.sum((S - s.wall_a) * s.wall_normals, axis=1)
        img = S - 2 * delta[:, None] * s.wall_normals
        far = np.hypot(*(img - C).T).max() + s.tip_radius_m
        L: float = max(2 * np.abs(delta).max(), np.hypot(*(S - C)) + s.tip_radius_m + far,
                2 * (np.hypot(*(S - C)) + s.tip_radius_m))
        return L / self.c * self.fs + 1.0

    def _resolve_dropouts(self, n_out: int) -> list[Dropout]:
        # a caller's value, checked here: a count or (output_index, samples) pairs
        spec: Any = self._dropout_spec
        L = self.dropout_samples
        if isinstance(spec, (int, np.integer)) and not isinstance(spec, bool):
            n = int(spec)
            if n < 0:
                raise ConfigError("dropouts", spec, "must be >= 0")
            if n == 0:
                return self._place([])
            room = n_out - n * L
            if room <= 0:
                raise ConfigError("dropouts", spec, f"{n} drop-outs of {L} samples do not fit "
                                  f"in {n_out} samples; use fewer or shorter ones")
            rng = np.random.default_rng([self.seed, 1])
            starts = np.sort(rng.integers(0, room, size=n)) + L * np.arange(n)
            return self._place([(int(a), L) for a in starts])
        try:
            pairs = [(int(a), int(b)) for a, b in spec]
        except (TypeError, ValueError):
            raise ConfigError("dropouts", spec, "must be a count or a list of "
                              "(output_index, samples) pairs") from None
        pairs.sort()
        for i, (a, b) in enumerate(pairs):
            if a < 0 or b < 1 or a >= n_out:
                raise ConfigError("dropouts", (a, b), f"output_index must be in [0, {n_out}) "
                                  "and samples >= 1")
            if self.dropout_mode == "zero" and i and a < pairs[i - 1][0] + pairs[i - 1][1]:
                raise ConfigError("dropouts", (a, b), "zeroed gaps must not overlap")
            if self.dropout_mode == "remove" and i and a == pairs[i - 1][0]:
                raise ConfigError("dropouts", (a, b), "two gaps at one output index; merge "
                                  "them into one")
        return self._place(pairs)

    def _place(self, pairs: list[tuple[int, int]]) -> list[Dropout]:
        out, shift = [], 0
        for a, b in pairs:
            if self.dropout_mode == "remove":
                out.append(Dropout(a, a + shift, b))
                shift += b
            else:
                out.append(Dropout(a, a, b))
        return out

    def prepare(self, seconds: float) -> dict[str, Any]:
        """Fix the run's length, drop-outs and noise level; returns the truth metadata."""
        if self.meta is not None and self.meta["seconds"] == seconds:
            return self.meta
        if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0):
            raise ConfigError("seconds", seconds, "must be a number of seconds > 0")
        n_out = int(round(seconds * self.fs))
        if n_out < 1:
            raise ConfigError("seconds", seconds, f"is shorter than one sample at {self.fs:g} Hz")
        self.n_out = n_out
        self.dropouts = self._resolve_dropouts(n_out)
        removed = sum(d.samples for d in self.dropouts) if self.dropout_mode == "remove" else 0
        self.n_capture = n_out + removed
        # pulses whose coupling edge lies inside the capture
        last = (self.n_capture / self.scale - self.offset) / self.pri
        self.n_pulses = max(0, int(math.ceil(last - 1e-12)))
        while self.n_pulses > 0 and self._edge(self.n_pulses - 1) >= self.n_capture:
            self.n_pulses -= 1
        self.sigma = 0.0
        p_fan: float | None = None
        ref: str | None = None
        self._p_echo = 0.0
        if self.snr_db is not None or self.nz.burst_fraction:
            p_fan, ref = self._reference_power()
            if self.snr_db is not None:
                self.sigma = math.sqrt(p_fan / 10 ** (self.snr_db / 10))
        self.bursts = _device.place_bursts(self.nz, self.seed, self.n_capture, self.fs)
        self.burst_rms = math.sqrt(self._p_echo * 10 ** (self.nz.burst_db / 10))
        g0, g1, gm = gate_samples(self.cfg)
        c = self.cfg
        self.meta = dict(
            format=TRUTH_FORMAT, seconds=seconds, samples=n_out, capture_samples=self.n_capture,
            pulses=self.n_pulses, scene=self.scene.describe(),
            config=dict(sample_rate=c.audio.sample_rate, pri_samples=self.pri,
                        prf_hz=self.fs / self.pri, pulse=c.waveform.pulse,
                        pulse_samples=c.waveform.pulse_samples, amplitude=self.amplitude,
                        speed_of_sound=self.c, blades=self.K),
            schedule=self.schedule.to_string(), seed=self.seed,
            start_offset_samples=self.offset, drift_ppm=self.drift_ppm,
            dropouts=dict(mode=self.dropout_mode,
                          runs=[dict(output_index=d.output_index, capture_index=d.capture_index,
                                     samples=d.samples) for d in self.dropouts]),
            dc_offset=self.dc_offset, clip=self.clip, wall_bounces=self.wall_bounces,
            nuisances=dict(
                settings=self.nz.active, speed_of_sound_room=self.c,
                speed_of_sound_config=self.c_cfg, speaker_taps=len(self.speaker),
                tail_pris=None if self.tail is None else self.nz.rt60_s * self.fs / self.pri,
                burst_rms=self.burst_rms if self.bursts else None,
                bursts=[dict(capture_index=b.capture_index, samples=b.samples)
                        for b in self.bursts],
                full_scale=_device.FULL_SCALE,
                order="speaker -> room (paths, late tail, walker) -> + noise + bursts -> "
                      "x mic gain and AGC -> dc offset -> clip level -> converter (clip at "
                      "full scale, quantise) -> drop-outs"),
            aliasing_limit_hz=self.alias_limit_hz,
            snr=dict(snr_db=self.snr_db, noise_sigma=self.sigma, fan_power=p_fan,
                     reference=ref, gate_m=list(gm), gate_samples=[g0, g1],
                     definition="10*log10(P_fan / sigma^2); P_fan = mean square of the "
                                "noise-free fan echo (blade, wall_blade, blade_wall paths) over "
                                "the samples inside the one-way range gate of every pulse; "
                                "sigma = std of the white Gaussian noise on every sample"),
            conventions=dict(
                angle="fan angle in rad, ccw positive in the floor plan (x right, y up, seen "
                      "from above); 0 = blade 0 along +x; phase = frac(K * angle / 2pi)",
                rate="rate_hz signed, + = ccw",
                delay="path delay in samples at the nominal rate, counted from the direct "
                      "coupling edge; one-way range = c * delay / fs / 2",
                sample="capture sample of the pulse's coupling edge in the output file "
                       "(after drift and drop-outs); null if it fell in a drop-out",
                time_s="true emission time of the pulse"),
        )
        if isinstance(self.scene, Scene3D):
            self.meta["conventions"].update(
                angle="fan angle in rad, ccw positive seen from below (x, y the floor plan "
                      "seen from above, z up; ccw from below turns +x towards -y); 0 = "
                      "blade 0 along +x; phase = frac(K * angle / 2pi)",
                rate="rate_hz signed, + = ccw seen from below; direction = rotation seen "
                     "from below",
                airflow="down or up: the sign of rate times the blades' pitch (+ pitch "
                        "blows down turning ccw seen from below); none at rest or with "
                        "flat blades")
        return self.meta

    def _edge(self, k: np.ndarray | int) -> np.ndarray:
        return (self.offset + np.asarray(k, dtype=np.float64) * self.pri) * self.scale

    # ------------------------------------------------------------------ geometry blocks
    def _block(self, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(delay samples (P, M), gain (P, M), valid (P, M)) for pulses of block b."""
        hit = self._blocks.get(b)
        if hit is not None:
            return hit
        k = np.arange(b * _PULSE_BLOCK, (b + 1) * _PULSE_BLOCK)
        t = (self.offset + k * float(self.pri)) / self.fs
        ang = self.schedule.angle_at(t, self.scene.start_angle_rad)
        tab = self.geo.path_table(self.scene, ang, wall_bounces=self.wall_bounces)
        d = np.where(tab.valid, tab.length_m, 0.0) / self.c * self.fs
        hit = (d, tab.gain, tab.valid)
        for old in [x for x in self._blocks if x < b - 1]:
            del self._blocks[old]
        self._blocks[b] = hit
        return hit

    def _pulse_rows(self, k0: int, k1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Geometry rows for pulses k0..k1-1 (concatenated from blocks)."""
        ds, gs, vs = [], [], []
        for b in range(k0 // _PULSE_BLOCK, (k1 - 1) // _PULSE_BLOCK + 1):
            d, g, v = self._block(b)
            lo = max(k0 - b * _PULSE_BLOCK, 0)
            hi = min(k1 - b * _PULSE_BLOCK, _PULSE_BLOCK)
            ds.append(d[lo:hi])
            gs.append(g[lo:hi])
            vs.append(v[lo:hi])
        return np.concatenate(ds), np.concatenate(gs), np.concatenate(vs)

    # ------------------------------------------------------------------ SNR reference
    def _reference_power(self) -> tuple[float, str]:
        g0, g1, _ = gate_samples(self.cfg)
        m_lo, m_hi = int(math.ceil(g0)), int(math.floor(g1))
        G = max(m_hi - m_lo + 1, 0)
        if G == 0 or self.n_pulses == 0:
            return self._coupling_power(), "coupling"
        sums = {"fan": 0.0, "all_echoes": 0.0}
        for k0 in range(0, self.n_pulses, _PULSE_BLOCK):
            k1 = min(k0 + _PULSE_BLOCK, self.n_pulses)
            d, g, v = self._pulse_rows(k0, k1)
            fan = np.isin(self._kind, self.geo.FAN_KINDS)[None, :] & v
            echo = (self._kind != "coupling")[None, :] & v
            for name, m in (("fan", fan), ("all_echoes", echo)):
                if name == "all_echoes" and sums["fan"] > 0 and not self.nz.burst_fraction:
                    continue
                rows = np.nonzero(m)[0]
                idx, w = waveform.shaped_taps(d[m], self.amplitude * g[m], self.shape)
                local = idx - m_lo
                inside = (local >= 0) & (local < G)
                flat = (rows[:, None] * G + local)[inside]
                buf = np.bincount(flat, weights=w[inside], minlength=(k1 - k0) * G)
                sums[name] += float(np.sum(buf * buf))
            self._blocks.clear()
        n = self.n_pulses * G
        self._p_echo = sums["all_echoes"] / n
        for name in ("fan", "all_echoes"):
            if sums[name] > 0:
                return sums[name] / n, name
        log.warning("no echo inside the range gate: noise level set from the coupling peak")
        return self._coupling_power(), "coupling"

    def _coupling_power(self) -> float:
        p = (self.amplitude * self.scene.coupling_gain) ** 2
        return p if p > 0 else self.amplitude ** 2

    # ------------------------------------------------------------------ rendering
    def _render_capture(self, n0: int, n1: int) -> np.ndarray:
        """Noise-free capture samples [n0, n1) of the uninterrupted stream."""
        H = waveform.HALF_TAPS
        tail = H + len(self.shape)
        lo = ((n0 - tail) / self.scale - self.offset - self._dmax) / self.pri
        hi = ((n1 + H) / self.scale - self.offset) / self.pri
        k0 = max(0, int(math.floor(lo)))
        k1 = min(self.n_pulses, int(math.ceil(hi)) + 1)
        if k1 <= k0:
            return np.zeros(n1 - n0)
        d, g, v = self._pulse_rows(k0, k1)
        k = np.arange(k0, k1, dtype=np.float64)[:, None]
        pos = ((self.offset + k * self.pri) + d) * self.scale
        pos, amp = pos[v], self.amplitude * g[v]
        if self.nz.walker_speed_m_s > 0 and isinstance(self.scene, Scene):
            t = (self.offset + k[:, 0] * self.pri) / self.fs
            length, gain, here = walker_paths(self.nz, self.scene, t)
            wp = ((self.offset + k[:, 0] * self.pri) + length / self.c * self.fs) * self.scale
            pos = np.concatenate([pos, wp[here]])
            amp = np.concatenate([amp, self.amplitude * gain[here]])
        near = (pos > n0 - tail - 1) & (pos < n1 + H + 1)
        idx, w = waveform.shaped_taps(pos[near], amp[near], self.shape)
        return waveform.render(idx, w, n0, n1 - n0)

    def _add_tail(self, x: np.ndarray, n0: int) -> None:
        """The late reverberation of every pulse whose tail reaches [n0, n0 + len(x))."""
        tl = self.tail
        if tl is None:
            return
        n1 = n0 + len(x)
        lo = ((n0 - tl.start - tl.length) / self.scale - self.offset) / self.pri
        hi = ((n1 - tl.start + waveform.HALF_TAPS) / self.scale - self.offset) / self.pri
        k0 = max(0, int(math.floor(lo)))
        k1 = min(self.n_pulses, int(math.ceil(hi)) + 1)
        if k1 <= k0:
            return
        k = np.arange(k0, k1)
        t = (self.offset + k * float(self.pri)) / self.fs
        ang = self.schedule.angle_at(t, self.scene.start_angle_rad)
        tl.add(x, n0, self._edge(k), np.mod(ang * self.K / (2 * math.pi), 1.0))

    def _add_bursts(self, x: np.ndarray, n0: int) -> None:
        """Interference bursts at the microphone overlapping [n0, n0 + len(x))."""
        n1 = n0 + len(x)
        for i, b in enumerate(self.bursts):
            a, e = max(b.capture_index, n0), min(b.capture_index + b.samples, n1)
            if a >= e:
                continue
            if self._burst_cache is None or self._burst_cache[0] != i:
                self._burst_cache = (i, _device.burst_samples(self.bursts, i, self.burst_rms,
                                                              self.seed, self.fs))
            z = self._burst_cache[1]
            x[a - n0:e - n0] += z[a - b.capture_index:e - b.capture_index]

    def _noise(self, n0: int, n1: int) -> np.ndarray:
        out = np.empty(n1 - n0)
        for b in range(n0 // _NOISE_BLOCK, (n1 - 1) // _NOISE_BLOCK + 1):
            if self._noise_cache is None or self._noise_cache[0] != b:
                z = np.random.default_rng([self.seed, 2, b]).standard_normal(_NOISE_BLOCK)
                self._noise_cache = (b, z)
            z = self._noise_cache[1]
            a, e = max(n0, b * _NOISE_BLOCK), min(n1, (b + 1) * _NOISE_BLOCK)
            out[a - n0:e - n0] = z[a - b * _NOISE_BLOCK:e - b * _NOISE_BLOCK]
        return out

    def _capture_index(self, m: int) -> int:
        """Capture index of output sample m (remove mode skips the gaps before it)."""
        if self.dropout_mode != "remove":
            return m
        return m + sum(d.samples for d in self.dropouts if d.output_index <= m)

    def _output_sample(self, pos: float) -> tuple[float | None, bool]:
        """Output position of capture position ``pos``; None if it fell in a drop-out."""
        shift = 0
        for d in self.dropouts:
            if d.capture_index <= pos < d.capture_index + d.samples:
                return None, True
            if self.dropout_mode == "remove" and pos >= d.capture_index + d.samples:
                shift += d.samples
        return pos - shift, False

    def _records(self, k0: int, k1: int) -> list[dict[str, Any]]:
        if k1 <= k0:
            return []
        k = np.arange(k0, k1)
        t = (self.offset + k * float(self.pri)) / self.fs
        ang = self.schedule.angle_at(t, self.scene.start_angle_rad)
        rate = self.schedule.rate_at(t)
        phase = np.mod(ang * self.K / (2 * math.pi), 1.0)
        phase = np.where(phase >= 1.0, 0.0, phase)
        dirs = _schedule.direction_of(rate)
        edges = self._edge(k)
        airflow = self.scene.airflow(rate) if isinstance(self.scene, Scene3D) else None
        if self.include_paths:
            d, g, v = self._pulse_rows(k0, k1)
        recs = []
        for i in range(k1 - k0):
            sample, dropped = self._output_sample(float(edges[i]))
            r: dict[str, Any] = dict(pulse=int(k[i]), time_s=float(t[i]), sample=sample,
                                     angle_rad=float(ang[i]), phase=float(phase[i]),
                                     rate_hz=float(rate[i]), direction=str(dirs[i]))
            if airflow is not None:
                r["airflow"] = str(airflow[i])
            if dropped:
                r["dropped"] = True
            if any(b.capture_index - self.pri < edges[i] < b.capture_index + b.samples
                   for b in self.bursts):
                r["burst"] = True        # a burst overlaps this pulse's PRI
            if self.include_paths:
                cols = np.nonzero(v[i])[0]
                r["paths"] = [dict(kind=str(self._kind[j]), delay=round(float(d[i, j]), 6),
                                   gain=float(f"{g[i, j]:.8g}")) for j in cols]
            recs.append(r)
        return recs

    def chunks(self, seconds: float, chunk_samples: int = DEFAULT_CHUNK_SAMPLES
               ) -> Iterator[tuple[np.ndarray, list[dict[str, Any]]]]:
        """Yield (float64 output samples, truth records of the pulses whose coupling edge
        falls in this stretch of capture) until ``round(seconds * fs)`` samples are out."""
        if isinstance(chunk_samples, bool) or not isinstance(chunk_samples, int) \
                or chunk_samples < 1:
            raise ConfigError("chunk_samples", chunk_samples, "must be an integer >= 1")
        self.prepare(seconds)
        self.clipped = 0
        kdone = 0
        for m0 in range(0, self.n_out, chunk_samples):
            m1 = min(m0 + chunk_samples, self.n_out)
            n0 = self._capture_index(m0)
            n1 = self._capture_index(m1) if m1 < self.n_out else self.n_capture
            x = self._render_capture(n0, n1)
            self._add_tail(x, n0)
            if self.sigma > 0:
                x += self.sigma * self._noise(n0, n1)
            self._add_bursts(x, n0)
            if self.nz.capture_gain_db or self.nz.agc_db:
                x *= _device.agc_gain(self.nz, self.seed, n0, n1 - n0, self.fs)
            keep = np.ones(n1 - n0, bool)
            for dr in self.dropouts:
                a, e = max(dr.capture_index, n0), min(dr.capture_index + dr.samples, n1)
                if a < e:
                    if self.dropout_mode == "remove":
                        keep[a - n0:e - n0] = False
                    else:
                        x[a - n0:e - n0] = 0.0
            x = x[keep]
            if self.dc_offset:
                x += self.dc_offset
            if self.clip is not None:
                over = np.abs(x) > self.clip
                self.clipped += int(np.count_nonzero(over))
                np.clip(x, -self.clip, self.clip, out=x)
            x, over = _device.convert(x, self.nz.bits)
            self.clipped += over
            # pulses whose edge lies in [n0, n1)
            kend = kdone
            while kend < self.n_pulses and self._edge(kend) < n1:
                kend += 1
            yield x, self._records(kdone, kend)
            kdone = kend


def simulate(scene: Scene | Scene3D, cfg: Config, seconds: float, schedule: Any = None,
             **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
    """Whole run in memory: (float64 samples, truth dict with meta, pulses, summary).

    For short runs (tests); keyword arguments as ``Simulator`` plus ``chunk_samples``.
    """
    chunk = kwargs.pop("chunk_samples", DEFAULT_CHUNK_SAMPLES)
    sim = Simulator(scene, cfg, schedule, **kwargs)
    parts, pulses = [], []
    for x, recs in sim.chunks(seconds, chunk):
        parts.append(x)
        pulses.extend(recs)
    meta = sim.meta
    assert meta is not None
    truth = dict(meta=meta, pulses=pulses, summary=dict(clipped_samples=sim.clipped))
    return np.concatenate(parts) if parts else np.zeros(0), truth
