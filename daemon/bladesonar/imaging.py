"""The numbers behind the pictures (pure numpy, no I/O, no matplotlib).

People tune a sonar by looking at it; these functions compute what the paper shows, from the
pipeline's own stages (``dsp.pulses.align``, ``dsp.gate``, ``dsp.rangedoppler``,
``dsp.fingerprint.envelope_features``), so a picture shows what the analysis sees:

rd_map            range-doppler power (dB) of a recording, with the gate the pipeline uses
backproject       ISAR image in the frame rotating with the fan (time-domain backprojection)
polar / spokes    the image resampled in (radius, angle) around the fan centre
rotation_match    best normalised correlation of two images over rotations (CW vs CCW)
distance_matrix   pairwise pulse-to-pulse matching distance (energy norm of the features)
stripe_slope      slope of that matrix's stripes = signed rate ratio (probe / reference)
path_ranges       one-way ranges of the simulated paths vs pulse number (scene geometry)

Range convention everywhere (DESIGN.md): one-way range in metres = c * delay / 2, the delay
counted from the direct-coupling leading edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import fft as sp_fft
from scipy import optimize

from .answer import Direction
from .dsp import fingerprint as fp
from .dsp.gate import Gate, find_target_range, make_gate, max_gate_stop
from .dsp.pulses import AlignedPulses, align
from .dsp.rangedoppler import range_doppler
from .errors import InputError

if TYPE_CHECKING:
    from .config import Config
    from .sim.scene import Scene

RANGE_LABEL = "one-way range (m) = c·delay/2 from the direct-coupling edge"


# --------------------------------------------------------------------------------------
# Pulses and gate


def full_gate(cfg: Config) -> Gate:
    """Every usable delay of a PRI (0 .. one PRI less the guard)."""
    return Gate(0, max_gate_stop(cfg.waveform.pri_samples), float(cfg.audio.sample_rate),
                float(cfg.scene.speed_of_sound))


def aligned(x: np.ndarray, cfg: Config, gate: Gate | None = None) -> AlignedPulses:
    """Aligned pulses of a recording over ``gate`` (default: the whole PRI)."""
    return align(np.asarray(x, dtype=np.float64), cfg.waveform.pri_samples,
                 gate or full_gate(cfg))


def valid_pulses(ap: AlignedPulses, max_pulses: int | None = None, start: int = 0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(pulses (n, L), edge times in samples (n,)) of the usable pulses, from ``start``."""
    v = np.nonzero(ap.valid)[0][start:]
    if max_pulses:
        v = v[:max_pulses]
    if len(v) < 2:
        raise InputError(f"only {len(v)} usable pulses; the picture needs at least 2: "
                         "record longer or check the recording")
    return ap.pulses[v], ap.edges[v]


def pipeline_gate(cfg: Config, power: np.ndarray | None = None, ref_gate: Gate | None = None
                  ) -> tuple[Gate, float | None]:
    """The gate the pipeline would use: the reference's, the config's, or (both null) from
    the first rising moving energy of ``power`` (dsp.gate.find_target_range) less
    ``analysis.gate_margin_m``; returns (gate, target range or None)."""
    if ref_gate is not None:
        return ref_gate, None
    s, fs, c = cfg.scene, cfg.audio.sample_rate, cfg.scene.speed_of_sound
    target = s.target_range_m
    start = s.gate_start_m
    if start is None:
        if target is None:
            if power is None:
                raise ValueError("power is needed to find the target range")
            target = find_target_range(power, fs, c)
        start = max(target - cfg.analysis.gate_margin_m, 0.0)
    try:
        return make_gate(start, s.gate_stop_m, c=c, fs=fs, pri=cfg.waveform.pri_samples), target
    except ValueError as exc:
        raise InputError(f"range gate: {exc}") from exc


# --------------------------------------------------------------------------------------
# Range-doppler


@dataclass(frozen=True)
class RDMap:
    """Range-doppler power of a recording.

    Attributes
    ----------
    doppler_hz : (D,) ascending, zero at D // 2.
    range_m : (L,) one-way range of every delay sample.
    power_db : (D, L) power in dB relative to the map's maximum.
    gate : the gate the pipeline uses on this recording.
    target_m : the target range found (None if the gate was given).
    pulses : pulses transformed.
    """

    doppler_hz: np.ndarray
    range_m: np.ndarray
    power_db: np.ndarray
    gate: Gate
    target_m: float | None
    pulses: int

    def peak(self, lo_m: float, hi_m: float, min_hz: float = 0.0) -> tuple[float, float]:
        """(doppler Hz, range m) of the strongest cell with range in [lo_m, hi_m] and
        |doppler| >= min_hz."""
        r = (self.range_m >= lo_m) & (self.range_m <= hi_m)
        d = np.abs(self.doppler_hz) >= min_hz
        sub = np.where(d[:, None] & r[None, :], self.power_db, -np.inf)
        i, j = np.unravel_index(int(np.argmax(sub)), sub.shape)
        return float(self.doppler_hz[i]), float(self.range_m[j])


def rd_map(x: np.ndarray, cfg: Config, *, max_pulses: int | None = None,
           ref_gate: Gate | None = None, window: str | None = "hann", pad: int = 1) -> RDMap:
    """Range-doppler map over the whole PRI: DFT along pulses (dsp.rangedoppler), static
    part removed, in dB; the pipeline's gate for marking it."""
    ap = aligned(x, cfg)
    p, _ = valid_pulses(ap, max_pulses)
    f, power = range_doppler(p, cfg.prf_hz, window=window, pad=pad)
    gate, target = pipeline_gate(cfg, power, ref_gate)
    g = full_gate(cfg)
    db = 10.0 * np.log10(power / max(float(power.max()), 1e-300) + 1e-30)
    return RDMap(f, g.ranges_m(), db, gate, target, len(p))


# --------------------------------------------------------------------------------------
# ISAR backprojection


def _analytic_upsampled(x: np.ndarray, up: int) -> np.ndarray:
    """Analytic signal of each row, band-limited interpolation by ``up``, shape (n, up*L)."""
    n, L = x.shape
    spec = sp_fft.fft(x, axis=1)
    h = np.zeros(L)
    h[0] = 1.0
    if L % 2 == 0:
        h[L // 2] = 1.0
        h[1:L // 2] = 2.0
    else:
        h[1:(L + 1) // 2] = 2.0
    spec = spec * h[None, :]
    big = np.zeros((n, up * L), dtype=complex)
    half = (L + 1) // 2
    big[:, :half] = spec[:, :half]
    if L % 2 == 0:
        big[:, L // 2] = spec[:, L // 2]
    return sp_fft.ifft(big, axis=1) * up


@dataclass(frozen=True)
class IsarImage:
    """Backprojected image in the fan frame (x right, y up, metres from the fan centre;
    blade 0 of a simulated scene along +x when the start angle is the scene's).

    ``image[iy, ix]`` at ``(axis_m[ix], axis_m[iy])``; magnitude, linear units.
    """

    image: np.ndarray
    axis_m: np.ndarray
    mode: str
    pulses: int
    rate_hz: float

    @property
    def extent_m(self) -> float:
        return float(self.axis_m[-1] + 0.5 * (self.axis_m[1] - self.axis_m[0]))


def backproject(pulses: np.ndarray, times_s: np.ndarray, *, delay0: float, fs: float, c: float,
                sensor: tuple[float, float], centre: tuple[float, float], rate_hz: float,
                start_rad: float = 0.0, extent_m: float = 1.0, n_pix: int = 256,
                mode: str = "envelope", up: int = 4, chunk: int = 16) -> IsarImage:
    """Time-domain backprojection into the frame rotating with the fan.

    Parameters
    ----------
    pulses : ndarray, shape (n, L)
        Aligned pulses with the static part removed; sample m is delay ``delay0 + m``
        samples after the direct-coupling edge.
    times_s : ndarray, shape (n,)
        Time of each pulse (its coupling edge), s.
    delay0, fs, c : float
        Delay of sample 0 (samples), sample rate (Hz), speed of sound (m/s).
    sensor, centre : (x, y)
        Sensor and fan centre in the floor plan, m.
    rate_hz : float
        Signed fan rate, turns per second, + = ccw.
    start_rad : float
        Fan angle at t = 0 (the image is rotated by any error in it).
    extent_m : float
        The image spans [-extent_m, extent_m] in x and y.
    mode : {"envelope", "coherent"}
        Sum the envelopes (robust to timing and rate errors) or the analytic samples
        (sharper when timing is exact).
    up : int
        Band-limited upsampling of the pulses before linear interpolation.

    Notes
    -----
    Pixel p (fan frame) sits at ``R(theta_n) p + centre`` at pulse n; its monostatic delay is
    ``2 |sensor - that point| / c``. Equivalently the sensor orbits the still fan at
    ``s_n = R(-theta_n)(sensor - centre)``, which is what is computed (one hypot per pixel
    and pulse, vectorised over blocks of pulses).
    """
    x = np.asarray(pulses, dtype=np.float64)
    t = np.asarray(times_s, dtype=np.float64)
    if x.ndim != 2 or len(x) != len(t) or len(x) < 1:
        raise ValueError(f"pulses (n, L) and times_s (n,) must agree, n >= 1, got shapes "
                         f"{x.shape} and {t.shape}")
    if mode not in ("envelope", "coherent"):
        raise ValueError(f"mode must be 'envelope' or 'coherent', not {mode!r}")
    n, L = x.shape
    a = _analytic_upsampled(x, up)
    data = np.abs(a) if mode == "envelope" else a
    Lu = data.shape[1]
    flat = np.concatenate([data, np.zeros((n, 1), dtype=data.dtype)], axis=1).ravel()
    axis = (np.arange(n_pix) + 0.5) / n_pix * 2 * extent_m - extent_m
    grid_x, grid_y = np.meshgrid(axis, axis)
    px, py = grid_x.ravel(), grid_y.ravel()
    th = start_rad + 2.0 * math.pi * rate_hz * t
    d = np.asarray(sensor, float) - np.asarray(centre, float)
    sx = np.cos(th) * d[0] + np.sin(th) * d[1]
    sy = -np.sin(th) * d[0] + np.cos(th) * d[1]
    k = 2.0 * fs / c * up
    acc = np.zeros(n_pix * n_pix, dtype=data.dtype)
    for i0 in range(0, n, chunk):
        i1 = min(i0 + chunk, n)
        pos = np.hypot(sx[i0:i1, None] - px[None, :], sy[i0:i1, None] - py[None, :]) * k \
            - delay0 * up
        j = np.floor(pos)
        w = pos - j
        j = j.astype(np.int64)
        out = (j < 0) | (j >= Lu - 1)
        j = np.where(out, Lu, j)  # the zero column
        base = (np.arange(i0, i1) * (Lu + 1))[:, None]
        v0 = flat[base + j]
        v1 = flat[base + np.where(out, Lu, j + 1)]
        acc += ((1.0 - w) * v0 + w * v1).sum(axis=0)
    img = np.abs(acc).reshape(n_pix, n_pix) / n
    return IsarImage(img, axis, mode, n, float(rate_hz))


def polar(img: IsarImage, *, n_r: int = 64, n_theta: int = 360, r_max: float | None = None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(radii (n_r,), angles rad (n_theta,), values (n_r, n_theta)) by bilinear sampling."""
    from scipy.ndimage import map_coordinates

    r_max = img.extent_m if r_max is None else r_max
    r = (np.arange(n_r) + 0.5) / n_r * r_max
    th = np.arange(n_theta) / n_theta * 2 * math.pi
    X = r[:, None] * np.cos(th)[None, :]
    Y = r[:, None] * np.sin(th)[None, :]
    step = img.axis_m[1] - img.axis_m[0]
    ix = (X - img.axis_m[0]) / step
    iy = (Y - img.axis_m[0]) / step
    v = map_coordinates(img.image, [iy.ravel(), ix.ravel()], order=1, mode="constant")
    return r, th, v.reshape(X.shape)


def spokes(img: IsarImage, k: int, r_lo: float, r_hi: float, *, n_theta: int = 720
           ) -> np.ndarray:
    """Angles (rad, ascending in [0, 2 pi)) of the ``k`` brightest spokes: peaks of the
    mean brightness over radii [r_lo, r_hi], each at least pi / k from the others."""
    r, th, v = polar(img, n_r=96, n_theta=n_theta)
    prof = v[(r >= r_lo) & (r <= r_hi)].mean(axis=0)
    sep = int(n_theta / (2 * k))
    found: list[int] = []
    p = prof.copy()
    for _ in range(k):
        i = int(np.argmax(p))
        found.append(i)
        lo = np.arange(i - sep + 1, i + sep) % n_theta
        p[lo] = -np.inf
    return np.sort(th[found])


def rotation_match(a: IsarImage, b: IsarImage, *, r_lo: float = 0.0, r_hi: float | None = None,
                   mirror: bool = False, n_theta: int = 720) -> tuple[float, float]:
    """Best normalised correlation of two images over rotations about the fan centre, and
    the rotation (rad) of ``b`` that gives it; ``mirror`` also tries ``b`` mirrored.

    Only the angular structure of the ring ``r_lo .. r_hi`` counts: each radius's mean over
    angle is removed first (else the bright centre and the radial fall-off, which every
    image has, would make any two images look alike).
    """
    r, _, pa = polar(a, n_r=96, n_theta=n_theta)
    _, _, pb = polar(b, n_r=96, n_theta=n_theta, r_max=a.extent_m)
    ring = (r >= r_lo) & (r <= (r_hi if r_hi is not None else r[-1]))
    pa = pa[ring] - pa[ring].mean(axis=1, keepdims=True)
    pb = pb[ring] - pb[ring].mean(axis=1, keepdims=True)
    best, best_rot = -1.0, 0.0
    fa = np.fft.rfft(pa, axis=1)
    for flip in ((False, True) if mirror else (False,)):
        q = pb[:, ::-1] if flip else pb
        cc = np.fft.irfft(fa * np.conj(np.fft.rfft(q, axis=1)), n=n_theta, axis=1).sum(axis=0)
        den = math.sqrt(float((pa * pa).sum() * (q * q).sum()))
        i = int(np.argmax(cc))
        val = float(cc[i]) / den if den > 0 else 0.0
        if val > best:
            best, best_rot = val, 2 * math.pi * i / n_theta
    return best, best_rot


# --------------------------------------------------------------------------------------
# Pulse-to-pulse matching distance


def features(pulses: np.ndarray, cfg: Config) -> np.ndarray:
    """The pipeline's match vectors of gated pulses, the recording's own mean pulse (its
    static room) removed first."""
    p = np.asarray(pulses, dtype=np.float64)
    return fp.envelope_features(p, p.mean(axis=0), kind=cfg.analysis.features,
                                smooth=cfg.analysis.envelope_smooth)


def distance_matrix(fa: np.ndarray, fb: np.ndarray) -> np.ndarray:
    """Squared energy-norm distance of every pair: ``D[i, j] = |fa_i - fb_j|^2`` (nA, nB)."""
    a = np.asarray(fa, dtype=np.float64)
    b = np.asarray(fb, dtype=np.float64)
    d = (a * a).sum(1)[:, None] - 2.0 * (a @ b.T) + (b * b).sum(1)[None, :]
    out: np.ndarray = np.maximum(d, 0.0)
    return out


@dataclass(frozen=True)
class Stripes:
    """Stripe geometry of a distance matrix (rows: recording A, columns: B).

    ``slope`` = d(row)/d(column) along a stripe = (B's blade rate) / (A's blade rate),
    signed: positive when both turn the same way. ``row_cycles`` and ``col_cycles`` are
    the blade periods per pulse of A and B (the stripe pattern's 2-D frequency).
    """

    slope: float
    row_cycles: float
    col_cycles: float
    strength: float
    offset: float = 0.0

    def lines(self, cols: np.ndarray, rows: int) -> list[np.ndarray]:
        """Row positions of the stripe centres (lowest distance) at columns ``cols``, one
        array per stripe crossing ``[0, rows)``: ``r_A i - r_B j = offset + n``."""
        c = np.asarray(cols, dtype=np.float64)
        base = self.col_cycles * c + self.offset
        lo = math.floor(float(base.min())) - 1
        hi = math.ceil(float((self.row_cycles * rows + base).max())) + 1
        out = []
        for n in range(lo, hi + 1):
            i = (base + n) / self.row_cycles
            if ((i >= 0) & (i < rows)).any():
                out.append(i)
        return out


def _dtft2(z: np.ndarray, fi: float, fj: float) -> float:
    ei = np.exp(-2j * np.pi * fi * np.arange(z.shape[0]))
    ej = np.exp(-2j * np.pi * fj * np.arange(z.shape[1]))
    return float(abs(ei @ z @ ej))


def stripe_slope(d: np.ndarray, *, pad: int = 4) -> Stripes:
    """Slope of the stripes of a pairwise distance matrix from its 2-D spectrum.

    The matrix is a function of ``r_A i - r_B j`` (the blade phases of the two pulses), so
    its spectrum lies on the line through ``(r_A, -r_B)`` and its harmonics. The peak is
    found on a zero-padded FFT (row frequency > 0), pulled back to the fundamental when a
    sub-multiple is also strong, and refined on the exact 2-D DTFT; slope = r_B / r_A.
    """
    z = np.asarray(d, dtype=np.float64)
    nA, nB = z.shape
    if nA < 8 or nB < 8:
        raise ValueError(f"the matrix needs at least 8 rows and columns, got {z.shape}")
    z = z - z.mean(axis=1, keepdims=True) - z.mean(axis=0, keepdims=True) + z.mean()
    z = z * np.hanning(nA)[:, None] * np.hanning(nB)[None, :]
    FA, FB = pad * nA, pad * nB
    S = np.abs(np.fft.fft2(z, s=(FA, FB)))
    fi = np.fft.fftfreq(FA)
    fj = np.fft.fftfreq(FB)
    keep = fi > 1.5 / nA
    S = np.where(keep[:, None], S, 0.0)
    i, j = np.unravel_index(int(np.argmax(S)), S.shape)
    gi, gj = float(fi[i]), float(fj[j])
    top = S[i, j]
    for h in (4, 3, 2):  # prefer the fundamental (harmonics of the faster one may alias)
        ci, cj = gi / h, gj / h
        if ci <= 1.0 / nA:
            continue
        if _dtft2(z, ci, cj) > 0.25 * top:
            gi, gj = ci, cj
            break
    def minus_power(v: np.ndarray) -> float:
        return -_dtft2(z, float(v[0]), float(v[1]))

    res = optimize.minimize(minus_power, np.array([gi, gj]),
                            method="Nelder-Mead",
                            options={"xatol": 1e-6, "fatol": 1e-9 * top, "maxiter": 400,
                                     "initial_simplex": [[gi, gj], [gi + 0.25 / FA, gj],
                                                         [gi, gj + 0.25 / FB]]})
    ri, rj = float(res.x[0]), float(res.x[1])
    # the distance is lowest where the phases agree: where the fundamental's cosine is -1
    ei = np.exp(-2j * np.pi * ri * np.arange(nA))
    ej = np.exp(-2j * np.pi * rj * np.arange(nB))
    phi = float(np.angle(ei @ z @ ej))
    off = (0.5 - phi / (2 * np.pi)) % 1.0
    return Stripes(slope=-rj / ri, row_cycles=ri, col_cycles=-rj,
                   strength=float(-res.fun) / max(float(np.abs(z).sum()), 1e-300),
                   offset=off)


# --------------------------------------------------------------------------------------
# Simulated path ranges


@dataclass(frozen=True)
class PathSeries:
    """One-way ranges (m) of candidate paths vs pulse; NaN where a path does not exist
    (not specular, or shadowed). ``range_m`` is (P, M); ``kind`` (M,)."""

    pulse: np.ndarray
    time_s: np.ndarray
    angle_rad: np.ndarray
    range_m: np.ndarray
    kind: np.ndarray


def path_ranges(scene: Scene, cfg: Config, rate_hz: float, n_pulses: int, *,
                start_rad: float | None = None, kinds: tuple[str, ...] = ("wall_blade",)
                ) -> PathSeries:
    """Ranges of the scene's fan paths at each pulse for a constant signed rate (+ = ccw).

    ``wall_blade`` and ``blade_wall`` have equal lengths (the same route both ways), so the
    default keeps one of them; ``("blade",)`` gives the direct blade echoes.
    """
    from .sim import geometry

    scene = scene.with_config(cfg)
    k = np.arange(int(n_pulses))
    t = k * cfg.waveform.pri_samples / cfg.audio.sample_rate
    a0 = scene.start_angle_rad if start_rad is None else start_rad
    ang = a0 + 2.0 * math.pi * rate_hz * t
    tab = geometry.path_table(scene, ang, wall_bounces=any(x != "blade" for x in kinds))
    cols = np.isin(tab.kind, kinds)
    r = np.where(tab.valid[:, cols], tab.length_m[:, cols] / 2.0, np.nan)
    return PathSeries(k, t, ang, r, tab.kind[cols])


# --------------------------------------------------------------------------------------
# Track rows (analyze --track)


@dataclass(frozen=True)
class TrackSeries:
    """``analyze --track`` rows as arrays for the track picture.

    ``track`` is the tracked phase unwrapped (reference blade periods; NaN while unlocked;
    its slope is the relative rate), ``sd`` its standard deviation (NaN if the rows do not
    carry ``track_sd``), ``matched`` every matched phase placed on the same unwrapped axis
    (the branch nearest the track). ``direction`` holds the running decision per row;
    ``reversals`` the times where it changes between ``same`` and ``reversed``.
    """

    t_s: np.ndarray
    track: np.ndarray
    sd: np.ndarray
    matched: np.ndarray
    quality: np.ndarray
    outlier: np.ndarray
    relative_rate: np.ndarray
    confidence: np.ndarray
    direction: np.ndarray
    reversals: np.ndarray


def _num(v: float | None) -> float:
    return float("nan") if v is None else float(v)


def track_series(rows: list[dict[str, Any]]) -> TrackSeries:
    """Arrays from the per-pulse rows (in pulse order)."""
    if not rows:
        raise InputError("no track rows: give the output of 'bladesonar analyze --track'")
    try:
        t = np.array([float(r["t_s"]) for r in rows])
        z = np.array([float(r["phase"]) for r in rows])
        q = np.array([float(r["quality"]) for r in rows])
        tp = np.array([_num(r.get("track_phase")) for r in rows])
        sd = np.array([_num(r.get("track_sd")) for r in rows])
        rel = np.array([_num(r.get("relative_rate")) for r in rows])
        conf = np.array([_num(r.get("confidence")) for r in rows])
        out = np.array([bool(r.get("outlier", False)) for r in rows])
        dirs = np.array([str(r.get("direction", Direction.UNKNOWN)) for r in rows])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"not analyze --track rows ({exc!r}); make them with 'bladesonar "
                         "analyze --track'") from exc
    track = np.full(len(t), np.nan)
    prev = None
    for i, p in enumerate(tp):
        if not math.isfinite(p):
            continue
        # after a gap the line restarts on the branch nearest its last value
        track[i] = p if prev is None else prev + ((p - prev + 0.5) % 1.0 - 0.5)
        prev = track[i]
    # matched phases on the track's branch (or their own value while unlocked)
    ref = np.where(np.isfinite(track), track, z)
    matched = ref + ((z - np.where(np.isfinite(tp), tp, z) + 0.5) % 1.0 - 0.5)
    sign = np.where(dirs == Direction.SAME, 1, np.where(dirs == Direction.REVERSED, -1, 0))
    known = np.nonzero(sign)[0]
    rev = [t[known[i]] for i in range(1, len(known)) if sign[known[i]] != sign[known[i - 1]]]
    return TrackSeries(t, track, sd, matched, q, out, rel, conf, dirs, np.array(rev))


def reversal_times(schedule: Any) -> np.ndarray:
    """Times (s) where a schedule starts turning against its previous moving direction
    (a stop in between does not hide a reversal): at the step of an unramped reversal, at
    the zero crossing of the signed rate inside a ramp through zero, and where the rate
    leaves zero after a stop or a spin-down. The speed wobble never changes the sign (its
    amplitude is below 0.5), so only the base rate's pieces matter."""
    from .sim.schedule import parse

    sch = parse(schedule, key="schedule")
    last, out = 0.0, []
    for p in sch.pieces:
        s0, s1 = np.sign(p.start_hz), np.sign(p.end_hz)
        moving = s0 if s0 != 0 else s1          # sign just after the piece starts
        if moving != 0:
            if last != 0 and moving != last:
                out.append(p.start_s)
            last = moving
        if s0 != 0 and s1 != 0 and s1 != s0:    # linear ramp through zero
            out.append(p.start_s + (p.end_s - p.start_s) * p.start_hz
                       / (p.start_hz - p.end_hz))
            last = s1
    return np.array(out, dtype=np.float64)
