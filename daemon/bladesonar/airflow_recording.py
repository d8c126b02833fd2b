"""A recording's airflow with no reference: align the pulses, gate them, measure (pure).

The gate is the config's (``scene.gate_start_m`` .. ``gate_stop_m``); a null start opens
it at ``AIRFLOW_GATE_START_M`` (past the direct coupling's ringing), a null stop at the
last unambiguous range.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .dsp import airflow as af
from .dsp.gate import make_gate
from .dsp.pulses import align
from .errors import InputError

#: Where the gate opens when the config leaves it open, m.
AIRFLOW_GATE_START_M = 0.3
#: First pulses left out: the reverberation of earlier pulses has not built up in them.
WARMUP_PULSES = 20


def recording_airflow(x: np.ndarray, cfg: Any) -> af.Airflow:
    """The airflow of a mono recording ``x`` (float samples) made with ``cfg``'s pulses."""
    fs, pri = float(cfg.audio.sample_rate), int(cfg.waveform.pri_samples)
    s = cfg.scene
    start = s.gate_start_m if s.gate_start_m is not None else AIRFLOW_GATE_START_M
    try:
        gate = make_gate(start, s.gate_stop_m, c=s.speed_of_sound, fs=fs, pri=pri)
    except ValueError as exc:
        raise InputError(f"range gate: {exc}") from exc
    pulses = align(np.asarray(x, dtype=np.float64), pri, gate, warmup=WARMUP_PULSES)
    return af.measure(pulses.pulses, pulses.valid, fs / pri)
