"""Reference building (pure, no I/O): a recording of the fan turning at a steady rate made
into the angular table the analysis matches against.

build_reference:  align -> gate (given, or from the target's doppler energy) -> period
                  (blade-pass rate, refined) -> fold all periods into an angular table.

The range-doppler map and the period search run only here, at reference time; the
analysis (analyzer.py) needs only the table, the mean pulse and the metadata. The
reference file (io/reference.py) stores a :class:`Reference`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np

from .answer import significant
from .config import AnalysisSettings, Config
from .dsp import aliasing
from .dsp import device as dev
from .dsp import fingerprint as fp
from .dsp.gate import Gate, find_target_range, make_gate, max_gate_stop
from .dsp.period import PeriodEstimate, drift_harmonic, estimate_period, sub_sample_cycle
from .dsp.pulses import (
    BURST,
    OK,
    WARMUP,
    AlignedPulses,
    PulseAligner,
    align_recording,
    check_recording,
    count_clipped,
    count_dropped,
    too_few_pulses,
)
from .dsp.rangedoppler import band_limited, range_doppler, without_shift_and_gain
from .dsp.stats import median
from .errors import EstimationError, InputError, ReferenceFileError

#: Share of the band (up to Nyquist) in which a reference's target range is looked for
#: (the moving energy of the range-doppler map; dsp.pulses.EDGE_BAND's reason).
TARGET_BAND = 0.7

#: Version of the reference contents; bump when the table's meaning changes.
REFERENCE_VERSION = 1


class ReferenceMeta(TypedDict, total=False):
    """A reference's metadata (the file's ``meta`` member, JSON): what it was made from
    and with. :func:`build_reference` writes every key but ``direction_contrast``,
    ``match_share`` and ``astray_share`` (only when they could be measured) and
    ``twin_bins`` (only when some bin has a twin); a file is checked for the keys it
    must hold when it is read (``io.reference``), and the older files lack some. ``id``
    is the daemon's (the file's sha256, 12 digits), never stored."""

    format: str
    version: int
    file_format: int
    sha256: str
    id: str
    depends: dict[str, Any]
    """The config values the reference is only valid with (:func:`depends_on`)."""
    gate_samples: list[int]
    gate_m: list[float]
    range_convention: str
    cycles_per_pulse: float
    blade_rate_hz: float
    rate_hz: float
    rpm: float
    prf_hz: float
    periods_folded: float
    phase_bins: int
    quality: float
    line_snr: float
    explained_lines: float
    direction: str
    """cw, ccw or unknown: the way the fan turned while it was recorded."""
    pulses: int
    used_pulses: int
    dropped_pulses: int
    target_range_m: float | None
    features: str
    min_bin_weight: float
    device: dict[str, Any] | None
    """The device figures (dsp/device.py) as they were; a file may hold null."""
    warmup_pulses: int
    warnings: list[str]
    direction_contrast: float
    match_share: float
    """Share of its pulses matched clearly at their own angle by a table of the other
    half (:func:`fingerprint.self_matches`); only when measurable (older files: none)."""
    astray_share: float
    """Share of those clear matches that landed at another angle (look-alikes); only
    when any was clear (older files: none)."""
    twin_bins: list[int]
    """Per table bin, the bin whose pulses its clear matches often came from, or -1
    (:func:`fingerprint.twin_bins`); only when some bin has one (older files: none)."""
    learned_by: str
    """Why the daemon learned it (service/learner.py: auto, relearn, speed, command);
    absent when a person made it with ``reference``."""


@dataclass
class Reference:
    """A stored reference rotation: the angular table and what it depends on.

    Attributes
    ----------
    table : ndarray, shape (B, L)
        Feature vectors by blade phase (bin b at phase b/B).
    mean_pulse : ndarray, shape (L,)
        The reference's static part (mean gated pulse).
    meta : ReferenceMeta
        JSON-able: ``depends`` (config values that must match at analysis), blade and
        rotation rate, direction, periods folded, quality, gate, ...
    """

    table: np.ndarray
    mean_pulse: np.ndarray
    meta: ReferenceMeta

    @property
    def cycles_per_pulse(self) -> float:
        return float(self.meta["cycles_per_pulse"])

    @property
    def gate(self) -> Gate:
        d = self.meta["depends"]
        return Gate(int(self.meta["gate_samples"][0]), int(self.meta["gate_samples"][1]),
                    float(d["audio.sample_rate"]), float(d["scene.speed_of_sound"]))

    def summary(self) -> dict[str, Any]:
        """The JSON summary ``bladesonar reference`` prints."""
        m: dict[str, Any] = dict(self.meta)
        keys = ("blade_rate_hz", "rate_hz", "rpm", "periods_folded", "quality", "gate_m",
                "pulses", "dropped_pulses", "direction", "phase_bins", "cycles_per_pulse",
                "target_range_m", "line_snr", "direction_contrast", "match_share",
                "astray_share", "features", "device",
                "warnings")
        out = {k: m[k] for k in keys if k in m}
        if "cycles_per_pulse" in out:
            # to 12 digits: its last ones differ between CPUs (a sum's order in numpy's
            # vector code), and the file keeps every digit
            out["cycles_per_pulse"] = significant(float(out["cycles_per_pulse"]), 12)
        return out


#: The direction contrast under which ``reference`` advises another place (under
#: ``aliasing.MIRROR_DOUBT_Z``, 2, the live analysis starts in doubt too). Between 2 and
#: 5 it tells the directions, but of 60 spent held-out rooms (1800001-2000020) 3 of the
#: 6 such places were in doubt for minutes or flipped (right 26-82 %; the others 93.8-97.1 %),
#: against none of the 6 at 5-8 (90-97 %) and 2 of the 46 above (83 and 85 %).
PLACE_CONTRAST = 5.0
#: Widest gap between the blade angles a reference's pulses show, in pulse steps (its
#: cycles per pulse), over which it is warned about. Folding a rate that is not near a
#: whole number of pulses per period fills the angles between pulses: 40 spent random
#: scenes' references (2700001-2800020) left at most 0.19 of a step open, the two slow
#: ones near 1/50 and 1/73 period per pulse 0.81 and 0.89, and one of those (a 0.227 Hz
#: fan matched at its own speed, where every pulse falls between the measured angles)
#: was in doubt three quarters of its day. Half a step lies between.
FILL_GAP = 0.5
#: What the warnings about a reference's speed advise (the daemon's keeper learns its own
#: such reference again at another speed: service/reference_keeper.py).
SPEED_ADVICE = "record the reference at another fan speed, a few percent faster or slower"
#: What the place warnings advise (tools/days.py acts on it as a user would).
PLACE_ADVICE = ("a place nearer a wall, further off the fan's axis, makes the wall echoes "
                "that tell the directions apart stronger")
#: The share of a reference's pulses matched clearly at their own angle
#: (:func:`fingerprint.self_matches`) under which ``reference`` advises a place nearer the
#: fan. Of 219 spent held-out scenes (2000001-3000020, as drawn) the 21 under 0.2 were
#: right a median 89 % of their days, 11 of them under 90 %, with 78 false and 55 missed
#: events; the 198 at 0.2 or more a median 97.5 %, 6 under 90 %, 29 false and 27 missed
#: (docs/dynamics.md, "How much of the fan a place shows").
MATCH_SHARE = 0.2
#: The share of the clear matches landing at another angle (look-alike glints) from which
#: it gives the same advice. Of the same scenes the 11 at 0.3 or more were right 69 % of
#: their days on average, 6 of them under 90 %; and two devices moved nearer to places at
#: 0.35 and 0.45 (spent 2700020, 2800018) were right 72-75 % there.
ASTRAY_SHARE = 0.3
#: What the match-share and astray-share warnings advise (tools/days.py acts on it as a
#: user would).
NEARER_ADVICE = ("a place nearer the fan, or on another side of it, shows its blades "
                 "longer and more plainly")


def depends_on(cfg: Config) -> dict[str, Any]:
    """Config values a reference is only valid with (checked when it is loaded)."""
    return {"audio.sample_rate": cfg.audio.sample_rate,
            "waveform.pri_samples": cfg.waveform.pri_samples,
            "waveform.pulse": cfg.waveform.pulse,
            "waveform.pulse_samples": cfg.waveform.pulse_samples,
            "scene.blades": cfg.scene.blades,
            "scene.speed_of_sound": cfg.scene.speed_of_sound,
            "analysis.features": cfg.analysis.features,
            "analysis.envelope_smooth": cfg.analysis.envelope_smooth}


def check_compatible(ref: Reference, cfg: Config) -> None:
    """Raise ReferenceFileError naming the first config value that differs from the
    reference's (and both values); an explicit gate must match the stored one."""
    want = depends_on(cfg)
    have = ref.meta.get("depends", {})
    for key, value in want.items():
        if key not in have:
            raise ReferenceFileError(f"the reference does not record {key}; make it again "
                                     "with 'bladesonar reference'")
        if have[key] != value:
            raise ReferenceFileError(
                f"the reference was made with {key} = {have[key]!r} but the config says "
                f"{value!r}; use the same config or record a new reference")
    g = ref.gate
    for key, val, stored in (("scene.gate_start_m", cfg.scene.gate_start_m, g.start),
                             ("scene.gate_stop_m", cfg.scene.gate_stop_m, g.stop)):
        if val is None:
            continue
        try:
            mine = make_gate(cfg.scene.gate_start_m or 0.0, cfg.scene.gate_stop_m,
                             c=cfg.scene.speed_of_sound, fs=cfg.audio.sample_rate,
                             pri=cfg.waveform.pri_samples)
        except ValueError as exc:
            raise InputError(str(exc)) from exc
        now = mine.start if key.endswith("start_m") else mine.stop
        if now != stored:
            raise ReferenceFileError(
                f"the reference was made with {key} = "
                f"{ref.meta['gate_m'][0 if key.endswith('start_m') else 1]:g} m but the config "
                f"says {val:g} m; use the same gate or record a new reference")


def _gate_for_reference(cfg: Config, full: AlignedPulses, prf: float) -> tuple[Gate, float | None]:
    s, fs, c, pri = cfg.scene, cfg.audio.sample_rate, cfg.scene.speed_of_sound, \
        cfg.waveform.pri_samples
    target = s.target_range_m
    start_m = s.gate_start_m
    if start_m is None:
        if target is None:
            v = full.valid
            # below TARGET_BAND of Nyquist: the top of the band holds the aligner's
            # interpolation error, which under clock drift turns with the sub-sample
            # position and made a strong static echo 0.35 m away look like the moving
            # target (a random scene at -17 ppm: target 0.315 m, the fan at 2.3 m); and
            # without each pulse's shift and gain against the mean: a clipped coupling
            # timed 0.08 sample rms off did the same to a wall 0.47 m away (target
            # 0.45 m, the fan at 3.4 m)
            p = without_shift_and_gain(band_limited(full.pulses[v], TARGET_BAND))
            _, power = range_doppler(p, prf)
            target = find_target_range(power, fs, c)
        start_m = max(target - cfg.analysis.gate_margin_m, 0.0)
    try:
        return make_gate(start_m, s.gate_stop_m, c=c, fs=fs, pri=pri), target
    except ValueError as exc:
        raise InputError(f"range gate: {exc}") from exc


#: Least range the gate holds past the fan's direct echo, m. The wall bounces that tell
#: the direction come up to about 3 m after it in the 3-7 m rooms the device is made for
#: (a bounce off a far wall adds about the wall's distance from the fan), and beyond one
#: PRI they fold into the next pulse's window, ahead of the gate. With 1.2 m here (the
#: tuning room's bounces come 0.3-2 m after the direct echo) a fan 3-3.9 m away in a
#: random room read the other way from its reference was often `unknown`, and its
#: reversals came late (docs/dynamics.md, "Wall bounces past the gate").
MIN_MULTIPATH_M = 2.5
#: Range past the fan's direct echo that the PRI :func:`unfolding_pri` names keeps, m
#: (more than ``MIN_MULTIPATH_M``, so that the gate it gives is not warned about again).
UNFOLD_M = 3.0


def folds_multipath(gate: Gate, target: float | None) -> bool:
    """Whether the fan is so far that its wall bounces fold past one PRI."""
    return target is not None and gate.stop_m - target < MIN_MULTIPATH_M


def unfolding_pri(cfg: Config, target: float) -> int:
    """The PRI (samples) that keeps echoes to ``UNFOLD_M`` past a fan at ``target`` m."""
    c, fs = cfg.scene.speed_of_sound, cfg.audio.sample_rate
    return int(math.ceil(2.0 * (target + UNFOLD_M) / c * fs))


def _fold_warning(cfg: Config, gate: Gate, target: float | None) -> list[str]:
    """A warning when the fan is so far that its multipath folds past one PRI."""
    if target is None or not folds_multipath(gate, target):
        return []
    fs, K = cfg.audio.sample_rate, cfg.scene.blades
    pri = unfolding_pri(cfg, target)
    return [f"the fan's echo comes from {target:.2f} m and the range gate ends at "
            f"{gate.stop_m:.2f} m (one PRI): wall bounces that tell the direction fold "
            f"into the next pulse, so directions may be unknown or wrong; set "
            f"waveform.pri_samples to {pri} or more (echoes to {target + UNFOLD_M:.1f} m; "
            f"the fastest fan followed becomes {fs / pri / (2 * K):.2f} Hz), or move the "
            "device nearer the fan"]


def _period(xv: np.ndarray, valid: np.ndarray, index: np.ndarray, a: AnalysisSettings
            ) -> tuple[PeriodEstimate, np.ndarray, np.ndarray]:
    """The blade period of the valid gated pulses ``xv`` (rows ``valid`` of ``index``),
    with their mean and envelope features; raises EstimationError."""
    mean = xv.mean(axis=0)
    feats = fp.envelope_features(xv, mean, kind=a.features, smooth=a.envelope_smooth)
    y = np.zeros((len(valid), xv.shape[1]))
    y[valid] = xv - mean
    f_all = np.zeros((len(valid), feats.shape[1]))
    f_all[valid] = feats - feats.mean(axis=0)
    est = estimate_period(y, index, features=f_all, min_periods=a.min_periods,
                          max_cycles_per_pulse=a.max_phase_per_pulse,
                          line_snr_min=a.line_snr_min)
    return est, mean, feats


def _off_the_drift(est: PeriodEstimate, xv: np.ndarray, valid: np.ndarray,
                   index: np.ndarray, cfg: Config, period: float, span: int
                   ) -> tuple[PeriodEstimate, list[str]]:
    """The period estimate, and a warning, when the rate found lies on the clock drift's
    sub-sample cycle (``period``: the aligner's PRI in capture samples). That cycle's
    pattern (the alignment's interpolation error on strong static echoes) lives at the
    top of the band, a fan's echoes across it, so the band below TARGET_BAND decides:
    the same line there is the fan's (a fan may turn there by chance: a held-out room's
    at 0.639 Hz, 29 ppm); another line is the fan's, hidden above by the drift's (3-D
    tuning scene 8: 3.54 Hz learned for a fan at 0.264 Hz, which the low band gives);
    none leaves the reference with a warning. The rate is checked, and so is the
    strongest line it was chosen to explain: a rate can explain a drift harmonic as one
    of its own aliased harmonics (held-out 7100013: the only strong line at twice the
    cycle, 0.315 per pulse at -121 ppm, taken as the second harmonic of 0.342, 1.94 Hz
    for a fan at 0.155 Hz whose own lines were too weak to be peaks)."""
    r = est.cycles_per_pulse
    h = drift_harmonic(r, period, span)
    of_line = h is None
    if of_line:
        h = drift_harmonic(est.strongest_line, period, span)
    if h is None:
        return est, []
    try:
        low: PeriodEstimate | None = _period(band_limited(xv, TARGET_BAND), valid, index,
                                             cfg.analysis)[0]
    except EstimationError:
        low = None
    if low is not None and abs(low.cycles_per_pulse - r) <= 1.0 / span:
        return est, []
    prf, blades = cfg.prf_hz, cfg.scene.blades
    ppm = (period / cfg.waveform.pri_samples - 1.0) * 1e6
    on = f"{'on' if h == 1 else f'at {h} times'} the cycle of the pulses' sub-sample " \
         f"position under this device's clock drift ({sub_sample_cycle(period):.5f} per " \
         f"pulse, {ppm:+.0f} ppm)"
    hz = r * prf / blades
    turned = "whose strongest line turned" if of_line else "turned"
    if low is not None:
        return low, [
            f"the strongest pattern ({hz:.3f} Hz) {turned} {on}: the alignment's error on "
            f"strong static echoes, not the fan; the rate is taken from the band below "
            f"{TARGET_BAND:g} of Nyquist, where the drift's pattern is not "
            f"({low.cycles_per_pulse * prf / blades:.3f} Hz). A place where the device "
            f"sees the blades better makes the fan's echoes stronger"]
    return est, [
        f"the pattern found turns {r:.5f} blade periods per pulse ({hz:.3f} Hz), "
        f"{'its strongest line ' if of_line else ''}{on}, "
        f"and the band below {TARGET_BAND:g} of Nyquist shows no pattern: if the fan "
        f"does not turn at {hz:.3f} Hz, the pattern is the alignment's interpolation "
        f"error on strong static echoes and the fan's echoes are too weak from here: "
        f"place the device where it sees the blades better (nearer the fan, 0.5-2 m off "
        f"its axis, nothing between)"]


def build_reference(x: np.ndarray, cfg: Config, direction: str = "unknown") -> Reference:
    """Make a reference from a recording of the fan turning at a steady rate.

    Parameters
    ----------
    x : ndarray, shape (n_samples,)
        Mono recording, float64 in [-1, 1].
    cfg : Config
        Validated settings.
    direction : {"cw", "ccw", "unknown"}
        The reference's known rotation (seen from the sensor), for absolute answers.

    Raises
    ------
    InputError, EstimationError
    """
    if direction not in ("cw", "ccw", "unknown"):
        raise ValueError(f"direction must be cw, ccw or unknown, got {direction!r}")
    a = cfg.analysis
    fs, pri = cfg.audio.sample_rate, cfg.waveform.pri_samples
    prf = cfg.prf_hz
    warnings = check_recording(x, pri=pri, min_pulses=a.min_pulses,
                               max_clip_fraction=a.max_clip_fraction, sample_rate=fs)
    full_gate = Gate(0, max_gate_stop(pri), float(fs), cfg.scene.speed_of_sound)
    full, aligner = align_recording(x, pri, full_gate)
    v = full.valid
    if v.sum() < a.min_pulses:
        raise too_few_pulses(int(v.sum()), len(full), len(x), pri=pri, sample_rate=fs,
                             min_pulses=a.min_pulses,
                             dropped=count_dropped(full.status, ended=True),
                             clipped=count_clipped(full.status))
    device, warm = _device_figures(full, aligner, prf, fs)
    warnings.extend(device.pop("warnings"))
    v = full.valid
    if v.sum() < a.min_pulses:
        raise too_few_pulses(int(v.sum()), len(full), len(x), pri=pri, sample_rate=fs,
                             min_pulses=a.min_pulses,
                             dropped=count_dropped(full.status, ended=True),
                             clipped=count_clipped(full.status))
    gate, target = _gate_for_reference(cfg, full, prf)
    warnings.extend(_fold_warning(cfg, gate, target))
    pulses = full.pulses[:, gate.start:gate.stop]
    k = full.index[v]
    xv = pulses[v]
    est, mean_pulse, feats = _period(xv, v, full.index, a)
    span = int(k[-1] - k[0]) + 1 if len(k) else 0
    est, drift_words = _off_the_drift(est, xv, v, full.index, cfg, aligner.period, span)
    warnings.extend(drift_words)
    r = est.cycles_per_pulse
    folded = aliasing.folded_angles(r, span)
    if folded is not None:
        p, q = folded.numerator, folded.denominator
        warnings.append(
            f"the reference turns {r:.6f} blade periods per pulse, within "
            f"{abs(r - p / q):.1e} of {p}/{q}: its {span} pulses show only {q} blade angles, "
            f"so the table holds only those (interpolated between) and the rate itself may "
            f"be an alias (another m/{q}; the record cannot tell the order of the angles); "
            f"{SPEED_ADVICE}")
    bins = fp.auto_bins(r, a.phase_bins,
                        angles=folded.denominator if folded is not None else None)
    phases = fp.fold_phases(k, r)
    gap = fp.largest_gap(phases) / r if r > 0 else 0.0
    if folded is None and gap > FILL_GAP:
        warnings.append(
            f"the reference turns {r:.6f} blade periods per pulse, so nearly a whole number "
            f"of pulses per period that its {span} pulses leave gaps of {gap:.2f} pulse "
            f"steps between the blade angles they show (folding fills them to under "
            f"{FILL_GAP:g} when the period is not a whole number of pulses): the table is "
            f"interpolated across them and a fan turning at this speed matches it poorly; "
            f"{SPEED_ADVICE}")
    table, weight = fp.build_table(feats, phases, bins)
    halves = fp.cross_tables(feats, phases, bins)
    crossed = fp.cross_matches(feats, phases, bins, halves)
    twins = fp.twin_bins(feats, phases, bins, crossed)
    quality = fp.explained_fraction(feats, table, phases)
    shares = fp.self_matches(feats, phases, bins, crossed)
    if shares.own < MATCH_SHARE:
        warnings.append(
            f"from here only {100 * shares.own:.0f} % of the fan's echoes match their own "
            f"blade angle clearly (under {100 * MATCH_SHARE:.0f} %): the blades are seen in "
            f"short glints, or two stretches of each blade period look alike, so the "
            f"track will often be lost and the answer unknown; {NEARER_ADVICE}")
    elif shares.astray_of_clear >= ASTRAY_SHARE:
        warnings.append(
            f"from here {100 * shares.astray_of_clear:.0f} % of the fan's clear echoes "
            f"match another blade angle better than their own ({100 * ASTRAY_SHARE:.0f} % "
            f"or more): two stretches of each blade period look alike, so the track will "
            f"often be lost or its direction in doubt; {NEARER_ADVICE}")
    window = max(int(round(cfg.daemon.window_s * prf)), 20)
    contrast = direction_contrast(feats, phases, bins, window, halves)
    if contrast is not None and contrast < aliasing.MIRROR_DOUBT_Z:
        warnings.append(
            f"from here the fan's echoes turned either way are nearly alike (direction "
            f"contrast {contrast:.1f} < {aliasing.MIRROR_DOUBT_Z:g}): the wall echoes that "
            f"tell the directions apart are weak, so the direction will often be unknown "
            f"and each new one waits for its own evidence; {PLACE_ADVICE}")
    elif contrast is not None and contrast < PLACE_CONTRAST:
        warnings.append(
            f"from here the fan's echoes turned either way differ only a little (direction "
            f"contrast {contrast:.1f} < {PLACE_CONTRAST:g}): the direction will at times be "
            f"unknown, or come late after a change; {PLACE_ADVICE}")
    blade_hz = r * prf
    rate_hz = blade_hz / cfg.scene.blades
    dropped = count_dropped(full.status, ended=True)
    if dropped:
        warnings.append(f"{dropped} pulses dropped or corrupt (not used)")
    meta: ReferenceMeta = {
        "format": "bladesonar-reference", "version": REFERENCE_VERSION,
        "depends": depends_on(cfg),
        "gate_samples": [gate.start, gate.stop],
        "gate_m": [round(gate.start_m, 4), round(gate.stop_m, 4)],
        "range_convention": "one-way range = c * delay / 2 from the direct-coupling edge",
        "cycles_per_pulse": r, "blade_rate_hz": round(blade_hz, 7),
        "rate_hz": round(rate_hz, 7), "rpm": round(rate_hz * 60.0, 5), "prf_hz": prf,
        "periods_folded": round(float(est.periods), 3), "phase_bins": bins,
        "quality": round(quality, 4), "line_snr": round(est.line_snr, 2),
        "explained_lines": round(est.explained, 4),
        "direction": direction, "pulses": int(len(full)), "used_pulses": int(v.sum()),
        "dropped_pulses": dropped,
        "target_range_m": None if target is None else round(float(target), 4),
        "features": a.features, "min_bin_weight": round(float(weight.min()), 3),
        "device": device, "warmup_pulses": warm,
        "warnings": warnings,
    }
    if contrast is not None:
        meta["direction_contrast"] = round(contrast, 2)
    if math.isfinite(shares.own):
        meta["match_share"] = round(shares.own, 3)
    if math.isfinite(shares.astray_of_clear):
        meta["astray_share"] = round(shares.astray_of_clear, 3)
    if (twins >= 0).any():
        meta["twin_bins"] = [int(t) for t in twins]
    return Reference(table=table, mean_pulse=mean_pulse, meta=meta)


def direction_contrast(feats: np.ndarray, phases: np.ndarray, bins: int, window: int,
                       halves: list[tuple[slice, np.ndarray]] | None = None
                       ) -> float | None:
    """How clearly the reference's own pulses tell their direction from its mirror: the
    median, over windows of the analysis's length, of :func:`aliasing.mirror_evidence` of
    each half's pulses against a table built from the other half
    (:func:`fingerprint.cross_tables`, or ``halves`` if made). None for too short a
    recording."""
    zs: list[float] = []
    for test, table in (halves if halves is not None else
                        fp.cross_tables(feats, phases, bins)):
        fine = aliasing.fine_table(table)
        f, p = feats[test], phases[test]
        for s0 in range(0, len(f) - aliasing.MIRROR_MIN_PULSES + 1, window):
            ev = aliasing.mirror_evidence(
                aliasing.distances(f[s0:s0 + window], fine), p[s0:s0 + window], fine)
            if ev.sweep >= aliasing.MIRROR_MIN_SWEEP and math.isfinite(ev.t):
                zs.append(ev.t)
    if not zs:
        return None
    zs.sort()                 # the median by hand: np.median imports numpy.ma (the daemon)
    m = len(zs) // 2
    return zs[m] if len(zs) % 2 else 0.5 * (zs[m - 1] + zs[m])


def _device_figures(full: AlignedPulses, aligner: PulseAligner, prf: float, fs: float
                    ) -> tuple[dict[str, Any], int]:
    """What the reference recording shows of the device and room (dsp/device.py), and the
    pulses a pulse train's start needs before its windows hold the whole reverberation.

    Marks in ``full.status`` the build-up pulses (WARMUP) and the bursts (BURST), so the
    reference is made of the steady, quiet pulses only.
    """
    warnings: list[str] = []
    v = full.valid
    x = full.pulses
    idx = np.nonzero(v)[0]
    late = idx[len(idx) // 2:]
    mean = x[late].mean(axis=0)
    # noise of one pulse from lag-1 differences over the late half of the window, where
    # the fan's echoes are weakest (an upper bound: the fan adds to it)
    L = x.shape[1]
    pair = late[1:][np.diff(late) == 1]
    if len(pair):
        d = x[pair, L // 2:] - x[pair - 1, L // 2:]
        noise_var = 0.5 * float(np.mean(d * d))
    else:
        noise_var = float(np.var(x[late, L // 2:]))
    zone = aligner.coupling_zone
    # bursts: a robust level of each pulse's residual (the median of its squares; the
    # fan's echoes are a few samples, a burst covers the window)
    v = full.valid
    res = x[v] - mean
    level = median(res * res, axis=1)
    burst = dev.burst_mask(level)
    full.status[np.nonzero(v)[0][burst]] = BURST
    v = full.valid
    gains = dev.projection_gains(x[v, zone:], mean[zone:])
    wander = dev.gain_wander_db(gains, prf)
    # every pulse brought to the mean's gain (an AGC's wander would otherwise leave a share
    # of the strong static echoes in every residual); the analysis does the same
    # (StaticRemover.skip_bursts)
    rows = np.nonzero(v)[0]
    good = np.isfinite(gains) & (gains > 0)
    if wander > dev.NORMALISE_ABOVE_DB:
        x[rows[good]] /= gains[good][:, None]
    # the room's tail: from the pulse train's start when the recording shows it (exact),
    # else from the static part's decay along the window (rough)
    ok = full.status == OK
    if wander > dev.NORMALISE_ABOVE_DB:
        mean = x[late[full.status[late] == OK]].mean(axis=0)
    n_lead = min(len(x), 400)
    lead = np.where(ok[:n_lead, None], x[:n_lead, zone:], np.nan)
    rt60, building = dev.tail_from_buildup(lead, mean[zone:], aligner.pri, fs)
    how = "build-up"
    if rt60 <= 0:
        rt60 = dev.tail_rt60(mean, noise_var / max(len(late), 1), fs, start=zone)
        how = "decay"
    warm = max(dev.buildup_pulses(rt60, prf) if how == "build-up" else 0, building)
    first = int(full.index[0]) if len(full) else 0
    full.status[(full.status == OK) & (full.index < first + warm)] = WARMUP
    measured = max(aligner.edges_measured, 1)
    clipped = aligner.coupling_clipped / measured
    figures = {
        "clipped_coupling": round(clipped, 4),
        "coupling_zone_samples": zone,
        "gain_wander_db": round(wander, 2) if math.isfinite(wander) else None,
        "burst_pulses": int(burst.sum()),
        "rt60_s": round(rt60, 3),
        "tail_pris": round(rt60 * prf, 1),
        "tail_from": how if rt60 > 0 else None,
        "warnings": warnings,
    }
    if clipped > 0:
        warnings.append(f"the direct coupling is clipped in {100 * clipped:.0f}% of the pulses "
                        "(handled: those edges follow the transmit schedule); a lower "
                        "playback volume or capture gain keeps more headroom")
    if wander > 3.0:
        warnings.append(f"the capture gain wanders by {wander:.1f} dB (an AGC?): turn the "
                        "microphone's automatic gain control off where the driver allows it")
    if burst.sum():
        warnings.append(f"{int(burst.sum())} pulses skipped for bursts of interference "
                        "(speech, clatter); record the reference in a quiet room")
    return figures, warm

