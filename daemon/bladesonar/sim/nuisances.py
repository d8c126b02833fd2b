"""What real devices and rooms add to the ideal scene: the settings, validated (pure).

One flat table of numbers (:data:`KEYS`), given in a scene file's ``nuisances:`` mapping or
on the command line as ``--nuisance KEY=VALUE`` (which wins). Each nuisance is rendered
where it happens physically (sim/render.py, sim/device.py, sim/reverb.py):

- transmit: the small speaker's response (``speaker_*``) shapes every path, the direct
  coupling included;
- room: late reverberation to an RT60 (``rt60_s``, ``reverb_*``, with a part that moves
  with the fan), a person walking through (``walker_*``), the speed of sound of the room
  now (``speed_of_sound``, against the config's that the analysis assumes);
- microphone: interference bursts (``burst_*``), then the gain (``capture_gain_db``) with
  an AGC's slow wander (``agc_*``);
- converter: clipping at full scale (always), quantisation (``bits``), then drop-outs.

All defaults are "absent", so a scene without the mapping renders as before.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from ..errors import ConfigError

#: key: (default, low, high, meaning). Ranges are inclusive.
KEYS: dict[str, tuple[float, float, float, str]] = {
    "capture_gain_db": (0.0, -120.0, 60.0, "microphone gain before the converter, dB "
                        "(e.g. -50 brings the fan echo to a few LSB of 16 bits)"),
    "bits": (0, 0, 32, "converter resolution: quantise to this many bits (0: float; a "
             "16-bit WAV quantises anyway)"),
    "speaker_highpass_hz": (0.0, 0.0, 5000.0, "small speaker: 2nd-order high-pass corner, "
                            "Hz (0: none)"),
    "speaker_resonance_hz": (0.0, 0.0, 15000.0, "small speaker: resonance, Hz (0: none)"),
    "speaker_q": (3.0, 0.5, 20.0, "quality factor of the speaker's resonance"),
    "speaker_resonance_db": (10.0, 0.0, 30.0, "peak of the resonance over the flat "
                             "response, dB"),
    "agc_db": (0.0, 0.0, 20.0, "microphone AGC: peak gain wander, dB (0: none)"),
    "agc_period_s": (8.0, 0.5, 600.0, "slowest period of the AGC's wander, s"),
    "burst_fraction": (0.0, 0.0, 0.5, "share of the time with interference bursts "
                       "(speech, clatter)"),
    "burst_db": (10.0, -40.0, 60.0, "burst power over the echoes' (all echoes in the "
                 "range gate), dB"),
    "burst_s": (0.3, 0.01, 10.0, "length of one burst, s"),
    "rt60_s": (0.0, 0.0, 3.0, "late reverberation: 60 dB decay time, s (0: none)"),
    "reverb_db": (0.0, -60.0, 30.0, "late tail's whole energy relative to the first-order "
                  "wall echoes' together, dB"),
    "reverb_fan_share": (0.02, 0.0, 1.0, "share of the tail's energy that comes by the fan "
                         "and changes with its angle"),
    "speed_of_sound": (0.0, 0.0, 2000.0, "the room's speed of sound now, m/s (0: the "
                       "config's scene.speed_of_sound; 343 + 0.6 per degree C)"),
    "walker_speed_m_s": (0.0, 0.0, 5.0, "a person walking across the room at this "
                         "speed, m/s (0: nobody)"),
    "walker_start_s": (2.0, 0.0, 1e6, "when the person enters (at the room's left "
                       "edge), s"),
    "walker_y_m": (-1.0, -1.0, 1000.0, "the line they walk along (y, metres); -1: "
                   "halfway between the sensor and the fan"),
    "walker_reflectivity": (1.0, 0.0, 10.0, "the person's echo gain (a blade is 1)"),
}


@dataclass(frozen=True)
class Nuisances:
    """The settings of :data:`KEYS`; every default is the ideal device and room."""

    capture_gain_db: float = 0.0
    bits: int = 0
    speaker_highpass_hz: float = 0.0
    speaker_resonance_hz: float = 0.0
    speaker_q: float = 3.0
    speaker_resonance_db: float = 10.0
    agc_db: float = 0.0
    agc_period_s: float = 8.0
    burst_fraction: float = 0.0
    burst_db: float = 10.0
    burst_s: float = 0.3
    rt60_s: float = 0.0
    reverb_db: float = 0.0
    reverb_fan_share: float = 0.02
    speed_of_sound: float = 0.0
    walker_speed_m_s: float = 0.0
    walker_start_s: float = 2.0
    walker_y_m: float = -1.0
    walker_reflectivity: float = 1.0

    @property
    def speaker(self) -> bool:
        return self.speaker_highpass_hz > 0 or self.speaker_resonance_hz > 0

    @property
    def active(self) -> dict[str, float]:
        """The settings that differ from the defaults (for truth files and summaries)."""
        base = Nuisances()
        return {f.name: getattr(self, f.name) for f in fields(self)
                if getattr(self, f.name) != getattr(base, f.name)}

    def describe(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def parse(data: Any, *, key: str = "nuisances", source: str | None = None,
          lines: Mapping[str, int] | None = None, base: Nuisances | None = None) -> Nuisances:
    """Validate a mapping of :data:`KEYS` (scene ``nuisances:``) over ``base``."""
    lines = lines or {}
    if data is None:
        return base or Nuisances()
    if not isinstance(data, Mapping):
        raise ConfigError(key, data, "must be a mapping of nuisance settings, e.g. "
                          "{rt60_s: 0.5, agc_db: 3}", source=source, line=lines.get(key))
    out: dict[str, Any] = dict((base or Nuisances()).describe())   # bits is an int
    for k, v in data.items():
        name = f"{key}.{k}"
        if k not in KEYS:
            close = difflib.get_close_matches(str(k), KEYS, 1)
            hint = f"; did you mean {close[0]}?" if close else ""
            raise ConfigError(name, v, f"unknown nuisance (known: {', '.join(KEYS)}){hint}",
                              source=source, line=lines.get(name, lines.get(key)))
        out[k] = _value(name, k, v, source, lines.get(name, lines.get(key)))
    return Nuisances(**out)


def parse_assignments(items: list[str] | None, base: Nuisances | None = None) -> Nuisances:
    """``KEY=VALUE`` strings from the command line (``--nuisance``) over ``base``."""
    data: dict[str, Any] = {}
    for item in items or []:
        k, sep, v = item.partition("=")
        if not sep:
            raise ConfigError("--nuisance", item, "must be KEY=VALUE, e.g. rt60_s=0.5 "
                              f"(keys: {', '.join(KEYS)})")
        try:
            data[k.strip()] = float(v)
        except ValueError:
            raise ConfigError(f"--nuisance {k.strip()}", v, "must be a number") from None
    return parse(data, key="--nuisance", base=base)


def _value(name: str, k: str, v: Any, source: str | None, line: int | None) -> float:
    default, lo, hi, meaning = KEYS[k]
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v)) \
        and lo <= float(v) <= hi
    if ok and k == "bits":
        ok = float(v) == int(v) and (int(v) == 0 or int(v) >= 4)
    if ok and k == "walker_y_m":
        ok = float(v) == -1.0 or float(v) >= 0.0
    if not ok:
        extra = " (a whole number: 0 or 4 to 32)" if k == "bits" else ""
        raise ConfigError(name, v, f"must be a number from {lo:g} to {hi:g}{extra}: {meaning}",
                          source=source, line=line)
    return int(v) if k == "bits" else float(v)


_SPEAKER = {"speaker_highpass_hz": 400.0, "speaker_resonance_hz": 2500.0}
_GAPS = {"dropouts": [(66150, 3 * 1297 + 500), (154350, 3 * 1297 + 500)]}

#: Named cases of ``bladesonar report``'s nuisance rows (and of the tests): (coupling gain
#: or None for the scene's, settings of the device and room in reference and probe alike,
#: settings of the probe only, extra schedule items of the probe, simulator keywords of the
#: probe). Drop-outs are at 1.5 s and 3.5 s of the probe, 3 PRIs and a bit each.
PRESETS: dict[str, tuple[float | None, dict, dict, str, dict]] = {
    "none": (None, {}, {}, "", {}),
    "clipped coupling (10x full scale)": (20.0, _SPEAKER, {}, "", {}),
    "reverberation RT60 0.5 s": (None, {"rt60_s": 0.5}, {}, "", {}),
    "reverberation RT60 0.7 s": (None, {"rt60_s": 0.7}, {}, "", {}),
    "small speaker": (None, _SPEAKER, {}, "", {}),
    "AGC +-3 dB": (None, {"agc_db": 3.0}, {}, "", {}),
    "16 bits, fan echo a few LSB": (None, {"capture_gain_db": -50.0, "bits": 16}, {}, "", {}),
    "5 degrees C warmer": (None, {}, {"speed_of_sound": 346.0}, "", {}),
    "person walking through": (None, {}, {"walker_speed_m_s": 1.0, "walker_start_s": 1.0},
                               "", {}),
    "bursts 10 % at +10 dB": (None, {"burst_fraction": 0.1}, {}, "", {}),
    "drop-outs of 3 PRIs": (None, {}, {}, "", _GAPS),
    "speed wobble 3 %": (None, {}, {}, ",wobble:0.03:2", {}),
    "all combined": (20.0, {"rt60_s": 0.5, "agc_db": 3.0, "burst_fraction": 0.1, **_SPEAKER},
                     {"speed_of_sound": 346.0, "walker_speed_m_s": 1.0,
                      "walker_start_s": 1.0}, ",wobble:0.03:2", _GAPS),
}
