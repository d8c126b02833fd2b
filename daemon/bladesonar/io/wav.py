"""Mono WAV in and out, with our own header parser.

Reading accepts 8/16/24/32-bit PCM and 32/64-bit float (plain or WAVE_FORMAT_EXTENSIBLE).
The header is walked chunk by chunk with every size checked against the file before
anything is read; samples are then read in blocks (:class:`WavReader`), so the memory of
reading is one block plus, for :func:`read_wav`, the float64 result, which is refused
before reading if longer than ``max_samples``. Header faults are one InputError naming
the file, the problem and the fix; a data chunk shorter than its header says (a recorder
killed mid-write) is read as far as it goes with a one-line warning.

Writing streams 16-bit PCM in chunks so that hours of simulated audio never sit in memory,
to a hidden temporary file renamed into place when complete (a full disk leaves nothing).
"""

from __future__ import annotations

import logging
import os
import stat
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..errors import InputError
from ..text import human_bytes
from .files import AtomicFile

log = logging.getLogger(__name__)

#: Longest recording :func:`read_wav` returns whole by default, samples: 6 Mi samples
#: (2 min 22 s at 44.1 kHz, 48 MiB as float64), held in under 200 MiB peak RSS by the
#: commands that need it whole (plots; measured). Longer ones are refused from the header,
#: before anything is read. ``analyze`` streams (:func:`stream_wav`) and has no limit.
MAX_SAMPLES = 6 << 20
#: What ``reference`` reads: the first 1 Mi samples (23.8 s at 44.1 kHz; a reference
#: needs 20 s). Building a reference costs about 5 MiB per second of audio, so longer
#: recordings are cut to this with a warning rather than read whole.
REFERENCE_SAMPLES = 1 << 20
#: Most chunks walked before the data chunk, and largest fmt chunk, bytes.
MAX_CHUNKS = 1000
MAX_FMT_BYTES = 1024
#: Samples per block of :meth:`WavReader.blocks`.
BLOCK_SAMPLES = 1 << 16

FIX = "record 16-bit PCM or 32-bit float mono WAV"
#: Largest float sample magnitude read (full scale = 1): 64-bit float samples beyond
#: float32's range are limited to it. Past full scale a sample counts as clipped whatever
#: its size, while products of samples near 1e300 overflow float64 in the analysis.
MAX_FLOAT_SAMPLE = float(np.finfo(np.float32).max)

_PCM, _FLOAT, _EXTENSIBLE = 1, 3, 0xFFFE


@dataclass(frozen=True)
class WavInfo:
    """What the header says, checked against the file."""

    rate: int
    channels: int
    bits: int
    float_format: bool
    data_offset: int
    frames: int

    @property
    def block_align(self) -> int:
        return self.channels * self.bits // 8

    @property
    def seconds(self) -> float:
        return self.frames / self.rate


def _bad(p: Path, problem: str) -> InputError:
    return InputError(f"{p}: not a readable WAV file ({problem}); {FIX}")


def parse_header(f: BinaryIO, size: int, p: Path) -> WavInfo:
    """Walk the RIFF chunks of an open file of ``size`` bytes up to the data chunk."""
    head = f.read(12)
    if len(head) < 12:
        raise _bad(p, f"{len(head)} bytes, shorter than a WAV header")
    if head[:4] != b"RIFF" or head[8:12] != b"WAVE":
        what = "RF64/big-endian WAV" if head[:4] in (b"RF64", b"RIFX") else "no RIFF/WAVE header"
        raise _bad(p, what)
    pos = 12
    fmt: tuple[int, int, int, int, int] | None = None
    for _ in range(MAX_CHUNKS):
        f.seek(pos)
        ch = f.read(8)
        if len(ch) < 8:
            raise _bad(p, "no data chunk" if fmt else "no fmt chunk")
        cid, csize = ch[:4], struct.unpack("<I", ch[4:])[0]
        body = pos + 8
        if cid == b"fmt ":
            if not 16 <= csize <= MAX_FMT_BYTES or body + csize > size:
                raise _bad(p, f"fmt chunk of {csize} bytes")
            raw = f.read(csize)
            tag, channels, rate, _, align, bits = struct.unpack("<HHIIHH", raw[:16])
            if tag == _EXTENSIBLE:
                if csize < 40:
                    raise _bad(p, "extensible fmt chunk too short")
                tag = struct.unpack("<H", raw[24:26])[0]
            fmt = (tag, channels, rate, align, bits)
        elif cid == b"data":
            if fmt is None:
                raise _bad(p, "data chunk before the fmt chunk")
            return _info(p, fmt, body, csize, size)
        elif body + csize > size:
            raise _bad(p, f"chunk {cid!r} of {human_bytes(csize)} runs past the end of "
                          "the file")
        pos = body + csize + (csize & 1)
    raise _bad(p, f"more than {MAX_CHUNKS} chunks before the data")


def _info(p: Path, fmt: tuple[int, int, int, int, int], offset: int, declared: int,
          size: int) -> WavInfo:
    tag, channels, rate, align, bits = fmt
    if tag not in (_PCM, _FLOAT):
        raise _bad(p, f"sample format tag {tag:#x}, not PCM or float")
    if channels == 0:
        raise _bad(p, "zero channels")
    if not 1000 <= rate <= 1_000_000:
        raise _bad(p, f"sample rate {rate} Hz")
    ok_bits = (8, 16, 24, 32) if tag == _PCM else (32, 64)
    if bits not in ok_bits:
        raise InputError(f"{p}: {bits}-bit {'float' if tag == _FLOAT else 'PCM'} samples are "
                         f"not supported; {FIX}")
    if align != channels * bits // 8:
        raise _bad(p, f"block align {align} for {channels} channels of {bits} bits")
    avail = size - offset
    if declared > avail:
        log.warning("%s: the data chunk says %d bytes but the file holds %d after the "
                    "header (cut short while recording?); reading what is there",
                    p, declared, max(avail, 0))
        declared = max(avail, 0)
    frames = declared // align
    if frames == 0:
        raise InputError(f"{p}: the WAV file holds no samples; {FIX}")
    return WavInfo(rate=rate, channels=channels, bits=bits, float_format=tag == _FLOAT,
                   data_offset=offset, frames=frames)


def _to_float(raw: bytes, info: WavInfo) -> np.ndarray:
    """Interleaved sample bytes -> float64 in [-1, 1] (first channel only)."""
    b = info.bits
    if info.float_format:
        # NaN and inf are kept: the analysis refuses them with its own message
        x = np.frombuffer(raw, dtype="<f4" if b == 32 else "<f8").astype(np.float64)
        if b == 64:
            big = np.abs(x) > MAX_FLOAT_SAMPLE
            if big.any():
                big &= np.isfinite(x)
                x[big] = np.copysign(MAX_FLOAT_SAMPLE, x[big])
    elif b == 8:
        x = (np.frombuffer(raw, dtype=np.uint8).astype(np.float64) - 128.0) / 128.0
    elif b == 16:
        x = np.frombuffer(raw, dtype="<i2").astype(np.float64) / 32768.0
    elif b == 24:
        u = np.frombuffer(raw, dtype=np.uint8).reshape(-1, 3).astype(np.int32)
        v = u[:, 0] | (u[:, 1] << 8) | (u[:, 2] << 16)
        x = np.where(v >= 1 << 23, v - (1 << 24), v).astype(np.float64) / 8388608.0
    else:
        x = np.frombuffer(raw, dtype="<i4").astype(np.float64) / 2147483648.0
    return x[::info.channels] if info.channels > 1 else x


class WavReader:
    """A WAV file opened for reading in blocks: memory is one block whatever its length."""

    def __init__(self, path: str | Path) -> None:
        self.path = p = Path(path)
        try:
            st = os.stat(p)
            if not stat.S_ISREG(st.st_mode):
                what = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
                raise InputError(f"{p}: is {what}; give the path of a mono WAV recording")
            self._f = open(p, "rb")
        except FileNotFoundError:
            raise InputError(f"{p}: no such file; give the path of a mono WAV "
                             "recording") from None
        except OSError as exc:
            raise InputError(f"{p}: cannot be read ({exc.strerror or exc}); check the "
                             "path") from None
        try:
            self.info = parse_header(self._f, os.fstat(self._f.fileno()).st_size, p)
        except OSError as exc:
            self._f.close()
            raise InputError(f"{p}: cannot be read ({exc.strerror or exc}); check the "
                             "disk") from None
        except BaseException:
            self._f.close()
            raise

    def blocks(self, block_samples: int = BLOCK_SAMPLES,
               max_frames: int | None = None) -> Iterator[np.ndarray]:
        """float64 blocks of the first channel, in order."""
        info = self.info
        left = info.frames if max_frames is None else min(info.frames, max_frames)
        self._f.seek(info.data_offset)
        while left > 0:
            n = min(block_samples, left)
            try:
                raw = self._f.read(n * info.block_align)
            except OSError as exc:
                raise InputError(f"{self.path}: cannot be read ({exc.strerror or exc}); "
                                 "check the disk") from None
            whole = len(raw) // info.block_align
            if whole == 0:
                return
            yield _to_float(raw[:whole * info.block_align], info)
            left -= whole

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> WavReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _check_usable(p: Path, info: WavInfo, expect_rate: int | None) -> None:
    """Refuse, from the header, what the analysis cannot use."""
    if info.channels != 1:
        raise InputError(f"{p}: has {info.channels} channels; bladesonar needs mono. "
                         f"Take one channel, e.g. 'sox {p.name} -c 1 mono.wav remix 1'")
    if expect_rate is not None and info.rate != expect_rate:
        raise InputError(f"{p}: sample rate is {info.rate} Hz but the config says "
                         f"audio.sample_rate = {expect_rate}; set audio.sample_rate: "
                         f"{info.rate} in the config (and a matching "
                         "waveform.pri_samples) or resample the recording")


@contextmanager
def stream_wav(path: str | Path, *, expect_rate: int | None = None
               ) -> Iterator[Iterator[np.ndarray]]:
    """A mono recording as float64 blocks in [-1, 1], checked from the header first:
    memory is one block whatever the recording's length (``analyze`` takes the blocks)."""
    with WavReader(path) as r:
        _check_usable(r.path, r.info, expect_rate)
        yield r.blocks()


def read_wav(path: str | Path, *, expect_rate: int | None = None,
             max_samples: int = MAX_SAMPLES, cut: bool = False) -> tuple[np.ndarray, int]:
    """Samples as float64 in [-1, 1] and the sample rate; refuses what analysis cannot use
    (from the header, before reading the samples). A recording longer than
    ``max_samples`` is refused, or with ``cut`` read only that far (a warning says so).
    ``analyze`` streams instead (:func:`stream_wav`)."""
    with WavReader(path) as r:
        p, info = r.path, r.info
        _check_usable(p, info, expect_rate)
        frames = info.frames
        if frames > max_samples and cut:
            log.warning("%s: %.0f s long; using its first %.1f s", p, info.seconds,
                        max_samples / info.rate)
            frames = max_samples
        elif frames > max_samples:
            keep = max_samples / info.rate
            raise InputError(f"{p}: {info.seconds:.0f} s long; this command reads at most "
                             f"{max_samples} samples ({keep:.0f} s at {info.rate} Hz); cut "
                             f"it, e.g. 'sox {p.name} part.wav trim 0 {keep:.0f}'")
        x = np.empty(frames, dtype=np.float64)
        n = 0
        for block in r.blocks(max_frames=frames):
            x[n:n + len(block)] = block
            n += len(block)
    return x[:n], int(info.rate)


class WavWriter:
    """Streams float samples in [-1, 1] to a 16-bit mono WAV; values beyond are clipped
    (and counted) so that a stress test's deliberate clipping and an accident look alike.

    The samples go to a hidden ``.NAME.XXXX.tmp`` in the same folder, renamed to ``path``
    by :meth:`close` after the header sizes are filled in and an fsync; :meth:`abort` (or
    leaving a ``with`` block by an exception) removes it, so a failed write (a full disk)
    never leaves a partial WAV.
    """

    def __init__(self, path: str | Path, rate: int) -> None:
        self.path = Path(path)
        self.rate = int(rate)
        self._out = AtomicFile(self.path)
        self._file = self._out.file
        self.frames = 0
        self.clipped = 0
        try:
            self._file.write(self._header(0))
        except BaseException:
            self.abort()
            raise

    def _header(self, frames: int) -> bytes:
        data = 2 * frames
        return (b"RIFF" + struct.pack("<I", 36 + data) + b"WAVEfmt "
                + struct.pack("<IHHIIHH", 16, 1, 1, self.rate, 2 * self.rate, 2, 16)
                + b"data" + struct.pack("<I", data))

    def write(self, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=np.float64)
        over = np.abs(x) > 32767.0 / 32768.0
        self.clipped += int(np.count_nonzero(over))
        q = np.clip(np.round(x * 32768.0), -32768, 32767).astype("<i2")
        self._file.write(q.tobytes())
        self.frames += len(q)

    def close(self) -> None:
        """Fill in the header sizes, fsync and rename into place."""
        def header() -> None:
            self._file.seek(0)
            self._file.write(self._header(self.frames))
        self._out.commit(header)

    def abort(self) -> None:
        """Drop the temporary file; ``path`` is left as it was."""
        self._out.abort()

    def __enter__(self) -> WavWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
