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

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from .. import schema
from ..errors import ConfigError
from ..schema import opt


def _setting(default: float, meaning: str, *, lo: float, hi: float) -> Any:
    """A nuisance setting: its meaning is said with a refused value too."""
    return opt(default, meaning, lo=lo, hi=hi, note=meaning)


@dataclass(frozen=True)
class Nuisances:
    """The settings, each with its default (the ideal device and room), meaning and range
    (inclusive): :data:`KEYS`."""

    capture_gain_db: float = _setting(
        0.0, "microphone gain before the converter, dB (e.g. -50 brings the fan echo to a few LSB "
        "of 16 bits)", lo=-120.0, hi=60.0)
    bits: int = _setting(
        0, "converter resolution: quantise to this many bits (0: float; a 16-bit WAV quantises "
        "anyway)", lo=0, hi=32)
    speaker_highpass_hz: float = _setting(
        0.0, "small speaker: 2nd-order high-pass corner, Hz (0: none)", lo=0.0, hi=5000.0)
    speaker_resonance_hz: float = _setting(
        0.0, "small speaker: resonance, Hz (0: none)", lo=0.0, hi=15000.0)
    speaker_q: float = _setting(3.0, "quality factor of the speaker's resonance", lo=0.5, hi=20.0)
    speaker_resonance_db: float = _setting(
        10.0, "peak of the resonance over the flat response, dB", lo=0.0, hi=30.0)
    agc_db: float = _setting(0.0, "microphone AGC: peak gain wander, dB (0: none)", lo=0.0, hi=20.0)
    agc_period_s: float = _setting(8.0, "slowest period of the AGC's wander, s", lo=0.5, hi=600.0)
    burst_fraction: float = _setting(
        0.0, "share of the time with interference bursts (speech, clatter)", lo=0.0, hi=0.5)
    burst_db: float = _setting(
        10.0, "burst power over the echoes' (all echoes in the range gate), dB", lo=-40.0, hi=60.0)
    burst_s: float = _setting(0.3, "length of one burst, s", lo=0.01, hi=10.0)
    rt60_s: float = _setting(
        0.0, "late reverberation: 60 dB decay time, s (0: none)", lo=0.0, hi=3.0)
    reverb_db: float = _setting(
        0.0, "late tail's whole energy relative to the first-order wall echoes' together, dB",
        lo=-60.0, hi=30.0)
    reverb_fan_share: float = _setting(
        0.02, "share of the tail's energy that comes by the fan and changes with its angle",
        lo=0.0, hi=1.0)
    speed_of_sound: float = _setting(
        0.0, "the room's speed of sound now, m/s (0: the config's scene.speed_of_sound; 343 + 0.6 "
        "per degree C)", lo=0.0, hi=2000.0)
    walker_speed_m_s: float = _setting(
        0.0, "a person walking across the room at this speed, m/s (0: nobody)", lo=0.0, hi=5.0)
    walker_start_s: float = _setting(
        2.0, "when the person enters (at the room's left edge), s", lo=0.0, hi=1e6)
    walker_y_m: float = _setting(
        -1.0, "the line they walk along (y, metres); -1: halfway between the sensor and the fan",
        lo=-1.0, hi=1000.0)
    walker_reflectivity: float = _setting(
        1.0, "the person's echo gain (a blade is 1)", lo=0.0, hi=10.0)

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


_FIELDS = schema.fields_of(Nuisances)
#: Every setting, in the order of :class:`Nuisances`.
KEYS = tuple(_FIELDS)


def parse(data: Any, *, key: str = "nuisances", source: str | None = None,
          lines: Mapping[str, int] | None = None, base: Nuisances | None = None) -> Nuisances:
    """Validate a mapping of :data:`KEYS` (scene ``nuisances:``) over ``base`` with the
    schema of :class:`Nuisances`."""
    lines = lines or {}
    if data is None:
        return base or Nuisances()
    if not isinstance(data, Mapping):
        raise ConfigError(key, data, "must be a mapping of nuisance settings, e.g. "
                          "{rt60_s: 0.5, agc_db: 3}", source=source, line=lines.get(key))
    schema.check_keys(data, KEYS, f"{key}.", lines, source, what="unknown nuisance")
    changes = {}
    for k, v in data.items():
        name = f"{key}.{k}"
        changes[k] = _check_special(name, k, schema.check_value(name, _FIELDS[k], v, lines,
                                                                source), lines, source)
    return dataclasses.replace(base or Nuisances(), **changes)


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


def _check_special(name: str, k: str, v: Any, lines: Mapping[str, int],
                   source: str | None) -> Any:
    """The two settings whose range has a hole: ``bits`` (0 or 4 to 32) and ``walker_y_m``
    (-1 or from 0)."""
    if k == "bits" and 0 < v < 4:
        raise ConfigError(name, v, "must be a whole number: 0 or 4 to 32 (converter "
                          "resolution; 0: float)", source=source, line=lines.get(name))
    if k == "walker_y_m" and v != -1.0 and v < 0.0:
        raise ConfigError(name, v, "must be -1 (halfway between the sensor and the fan) or "
                          "a number from 0 to 1000", source=source, line=lines.get(name))
    return v


_SPEAKER = {"speaker_highpass_hz": 400.0, "speaker_resonance_hz": 2500.0}
_GAPS = {"dropouts": [(66150, 3 * 1297 + 500), (154350, 3 * 1297 + 500)]}

#: Named cases of ``bladesonar report``'s nuisance rows (and of the tests): (coupling gain
#: or None for the scene's, settings of the device and room in reference and probe alike,
#: settings of the probe only, extra schedule items of the probe, simulator keywords of the
#: probe). Drop-outs are at 1.5 s and 3.5 s of the probe, 3 PRIs and a bit each.
PRESETS: dict[str, tuple[float | None, dict[str, Any], dict[str, Any], str,
                          dict[str, Any]]] = {
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
