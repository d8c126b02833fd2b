"""A recording's airflow with no reference: align the pulses, gate them, measure (pure).

The gate is the config's (``scene.gate_start_m`` .. ``gate_stop_m``); a null start opens
it at ``AIRFLOW_GATE_START_M`` (past the direct coupling's ringing), a null stop at the
last unambiguous range.

Also what the airflow means for a reference's direction (``bladesonar reference`` and the
daemon's learner) and the rate from the blade period on the same pulses (the daemon's
answer before its first reference exists).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .dsp import airflow as af
from .dsp import fingerprint as fp
from .dsp.gate import Gate, make_gate
from .dsp.pulses import AlignedPulses, PulseAligner
from .errors import EstimationError, InputError

#: Where the gate opens when the config leaves it open, m.
AIRFLOW_GATE_START_M = 0.3
#: First pulses left out: the reverberation of earlier pulses has not built up in them.
WARMUP_PULSES = 20
#: Samples fed to the aligner at a time (the same pulses as all at once, without the
#: aligner's whole-recording temporaries: 23 MiB of them for 2^20 samples).
ALIGN_CHUNK = 1 << 16


def _gate(cfg: Any) -> Gate:
    fs, pri = float(cfg.audio.sample_rate), int(cfg.waveform.pri_samples)
    s = cfg.scene
    start = s.gate_start_m if s.gate_start_m is not None else AIRFLOW_GATE_START_M
    try:
        return make_gate(start, s.gate_stop_m, c=s.speed_of_sound, fs=fs, pri=pri)
    except ValueError as exc:
        raise InputError(f"range gate: {exc}") from exc


def _aligned(x: np.ndarray | Iterable[np.ndarray], cfg: Any) -> AlignedPulses:
    g = _gate(cfg)
    a = PulseAligner(int(cfg.waveform.pri_samples), g, warmup=WARMUP_PULSES)
    if isinstance(x, np.ndarray):
        x = [x[i:i + ALIGN_CHUNK] for i in range(0, max(len(x), 1), ALIGN_CHUNK)]
    parts = [a.push(b) for b in x]
    parts.append(a.flush())
    return AlignedPulses.concat(parts, g.length)


def recording_airflow(x: np.ndarray | Iterable[np.ndarray], cfg: Any) -> af.Airflow:
    """The airflow of a mono recording ``x`` (float samples, or its blocks in order: the
    samples are then never all held) made with ``cfg``'s pulses."""
    pulses = _aligned(x, cfg)
    return af.measure(pulses.pulses, pulses.valid, cfg.audio.sample_rate
                      / cfg.waveform.pri_samples, overwrite=True)


def rotation_of(airflow: str, downdraft_rotation: str) -> str | None:
    """cw/ccw seen from below for an airflow (``scene.downdraft_rotation`` turns down
    into a rotation, up into the other one); None when the airflow is unknown."""
    if airflow not in ("down", "up"):
        return None
    if airflow == "down":
        return downdraft_rotation
    return "cw" if downdraft_rotation == "ccw" else "ccw"


def airflow_keys(a: af.Airflow, cfg: Any) -> dict[str, Any]:
    """The ``airflow*`` keys of ``analyze``/``reference`` output, ``airflow_rotation``
    included."""
    out = a.as_dict()
    out["airflow_rotation"] = rotation_of(a.airflow, cfg.scene.downdraft_rotation)
    return out


def reference_direction(given: str | None, a: af.Airflow, cfg: Any,
                        carried: str | None = None) -> tuple[str, str, list[str]]:
    """The direction a new reference is stored with: (direction, where it came from,
    warnings). A given cw/ccw wins (``given``: a person chose it); else a ``carried``
    cw/ccw (``carried``: the rotation the running estimates reported against the old
    reference, whose direction a person set or the daemon already reported, so a new
    reference keeps the frame the user sees); else a confident airflow sets it
    (``airflow``); else it stays ``unknown`` (``none``). A given or carried direction that
    a confident airflow contradicts is kept, with a warning that has the figures."""
    turn = rotation_of(a.airflow, cfg.scene.downdraft_rotation)
    if given == "unknown":
        return "unknown", "given", []
    for chosen, source in ((given, "given"), (carried, "carried")):
        if chosen not in ("cw", "ccw"):
            continue
        warnings = []
        if turn is not None and turn != chosen:
            what = (f"the direction given ({chosen})" if source == "given" else
                    f"the direction carried from the estimates against the previous "
                    f"reference ({chosen})")
            fix = ("check it (or leave it out and let the airflow set it)" if source ==
                   "given" else "if the airflow is right, set the reference's direction "
                   "to it")
            warnings.append(
                f"{what} contradicts the airflow measured on the recording: {a.airflow} "
                f"(confidence {a.confidence:.2f}, t {a.t:+.1f}, glint shift {a.shift:+.3f} "
                f"samples per pulse), which with scene.downdraft_rotation "
                f"{cfg.scene.downdraft_rotation} means {turn}; the direction {source} is "
                f"stored, {fix}")
        return chosen, source, warnings
    if turn is not None:
        return turn, "airflow", []
    return "unknown", "none", []


@dataclass(frozen=True)
class WindowFigures:
    """What a stretch of the capture says with no reference: the airflow, and the rate
    from the blade period (None when not asked for or not found)."""

    airflow: af.Airflow
    rotation: str | None
    rate_hz: float | None = None
    rate_reason: str | None = None

    def fields(self) -> dict[str, Any]:
        return {"airflow": self.airflow.airflow,
                "airflow_confidence": round(self.airflow.confidence, 4),
                "airflow_t": round(self.airflow.t, 2),
                "airflow_reason": self.airflow.reason}


def window_figures(x: np.ndarray, cfg: Any, *, rate: bool = False) -> WindowFigures:
    """The airflow of ``x`` and, with ``rate``, the fan's rate from its blade period on
    the same aligned pulses (the envelope features and the period estimate a reference
    is built with, analysis.build_reference)."""
    pulses = _aligned(x, cfg)
    prf = cfg.audio.sample_rate / cfg.waveform.pri_samples
    a = af.measure(pulses.pulses, pulses.valid, prf)
    turn = rotation_of(a.airflow, cfg.scene.downdraft_rotation)
    if not rate:
        return WindowFigures(a, turn)
    from .dsp.period import estimate_period

    v = pulses.valid
    if v.sum() < 16:
        return WindowFigures(a, turn, None, "too few usable pulses for the blade period")
    an = cfg.analysis
    xv = pulses.pulses[v]
    mean_pulse = xv.mean(axis=0)
    feats = fp.envelope_features(xv, mean_pulse, kind=an.features, smooth=an.envelope_smooth)
    y = np.zeros_like(pulses.pulses)
    y[v] = xv - mean_pulse
    f_all = np.zeros_like(pulses.pulses)
    f_all[v] = feats - feats.mean(axis=0)
    try:
        est = estimate_period(y, pulses.index, features=f_all, min_periods=an.min_periods,
                              max_cycles_per_pulse=an.max_phase_per_pulse,
                              line_snr_min=an.line_snr_min)
    except EstimationError as exc:
        return WindowFigures(a, turn, None, str(exc))
    return WindowFigures(a, turn, float(est.cycles_per_pulse * prf / cfg.scene.blades),
                         None)


@dataclass(frozen=True)
class ReferenceAirflow:
    """The airflow of a reference's recording and the direction it is stored with."""

    direction: str
    source: str
    """``given`` (by the user), ``carried`` (from the running estimates), ``airflow``
    (set by the measured airflow) or ``none``."""
    warnings: tuple[str, ...]
    keys: dict[str, Any]
    """The ``airflow*`` keys (:func:`airflow_keys`) and ``direction_source``."""


def reference_airflow(x: np.ndarray, cfg: Any, given: str | None,
                      carried: str | None = None) -> ReferenceAirflow:
    """Measure the airflow on a reference's recording ``x`` and choose its direction
    (:func:`reference_direction`). A recording the stage cannot use (a gate that does not
    fit) is an unknown airflow: the reference itself says what is wrong with it."""
    try:
        a = recording_airflow(x, cfg)
    except InputError as exc:
        a = af.Airflow("unknown", 0.0, 0.0, 0.0, 0, str(exc))
    direction, source, warnings = reference_direction(given, a, cfg, carried)
    keys = airflow_keys(a, cfg)
    keys["direction_source"] = source
    return ReferenceAirflow(direction, source, tuple(warnings), keys)


@dataclass(frozen=True)
class RangeTime:
    """The moving echoes' envelopes against pulse time and range (the stage's step 2:
    static room removed both ways, weighted, slow part removed), with the airflow the
    stage measures on the whole recording and its glint slope."""

    image: np.ndarray
    """(pulses, ranges): envelope of the moving echoes; pulses not usable are zero."""
    time_s: np.ndarray
    """Each row's time from the first aligned pulse, s."""
    range_m: np.ndarray
    """Each column's one-way range, m."""
    airflow: af.Airflow
    slope_m_s: float
    """The glints' one-way range change, m/s (- approaching: down)."""


def range_time(x: np.ndarray, cfg: Any, *, start_s: float = 0.0,
               seconds: float | None = None) -> RangeTime:
    """The range-time picture of ``x`` (``bladesonar plot airflow``): the whole recording's
    envelopes and airflow (the stage needs seconds of pulses), then the rows from
    ``start_s`` for ``seconds``."""
    pulses = _aligned(x, cfg)
    fs = float(cfg.audio.sample_rate)
    prf = fs / cfg.waveform.pri_samples
    a = af.measure(pulses.pulses, pulses.valid, prf)
    res, ok, static = af.moving_part(pulses.pulses, pulses.valid, prf)
    img = np.maximum(af.envelope_image(res, ok, static, prf, overwrite=True), 0.0)
    g = _gate(cfg)
    t = (pulses.index - (pulses.index[0] if len(pulses.index) else 0)) / prf
    keep = t >= start_s
    if seconds is not None:
        keep &= t < start_s + seconds
    if not keep.any():
        raise InputError(f"no pulses from {start_s:g} s for {seconds} s: the recording "
                         f"holds {t[-1] if len(t) else 0.0:.1f} s of pulses")
    c = float(cfg.scene.speed_of_sound)
    r = (g.start + np.arange(img.shape[1])) * c / (2.0 * fs)
    slope = a.shift * c / (2.0 * fs) * prf
    return RangeTime(img[keep], t[keep], r, a, float(slope))
