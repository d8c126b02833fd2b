"""Mono WAV in and out. Reading accepts 16/32-bit PCM and 32/64-bit float; writing streams
16-bit PCM in chunks so that hours of simulated audio never sit in memory."""

from __future__ import annotations

import wave
from pathlib import Path

import numpy as np

from ..errors import InputError


def read_wav(path: str | Path, *, expect_rate: int | None = None) -> tuple[np.ndarray, int]:
    """Samples as float64 in [-1, 1] and the sample rate; refuses what analysis cannot use."""
    from scipy.io import wavfile

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file; give the path of a mono WAV recording")
    try:
        rate, data = wavfile.read(p, mmap=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"{p}: not a readable WAV file ({exc}); record 16-bit PCM or "
                         "32-bit float mono WAV") from exc
    if data.ndim != 1:
        if data.ndim == 2 and data.shape[1] == 1:
            data = data[:, 0]
        else:
            raise InputError(f"{p}: has {data.shape[1]} channels; bladesonar needs mono. "
                             f"Take one channel, e.g. 'sox {p.name} -c 1 mono.wav remix 1'")
    if expect_rate is not None and rate != expect_rate:
        raise InputError(f"{p}: sample rate is {rate} Hz but the config says "
                         f"audio.sample_rate = {expect_rate}; set audio.sample_rate: {rate} "
                         "in the config (and a matching waveform.pri_samples) or resample "
                         "the recording")
    if data.dtype == np.int16:
        x = data.astype(np.float64) / 32768.0
    elif data.dtype == np.int32:
        x = data.astype(np.float64) / 2147483648.0
    elif data.dtype == np.uint8:
        x = (data.astype(np.float64) - 128.0) / 128.0
    elif data.dtype in (np.float32, np.float64):
        x = data.astype(np.float64)
    else:
        raise InputError(f"{p}: sample type {data.dtype} is not supported; use 16-bit PCM "
                         "or 32-bit float")
    return x, int(rate)


class WavWriter:
    """Streams float samples in [-1, 1] to a 16-bit mono WAV; values beyond are clipped
    (and counted) so that a stress test's deliberate clipping and an accident look alike."""

    def __init__(self, path: str | Path, rate: int) -> None:
        self.path = Path(path)
        self._w = wave.open(str(self.path), "wb")
        self._w.setnchannels(1)
        self._w.setsampwidth(2)
        self._w.setframerate(int(rate))
        self.frames = 0
        self.clipped = 0

    def write(self, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=np.float64)
        over = np.abs(x) > 32767.0 / 32768.0
        self.clipped += int(np.count_nonzero(over))
        q = np.clip(np.round(x * 32768.0), -32768, 32767).astype("<i2")
        self._w.writeframesraw(q.tobytes())
        self.frames += len(q)

    def close(self) -> None:
        self._w.close()

    def __enter__(self) -> "WavWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
