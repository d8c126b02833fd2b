"""Reference files: the angular table and its metadata in one versioned, checksummed .npz.

Layout: arrays ``table`` (B, L) and ``mean_pulse`` (L,) as float64, and ``meta`` holding
one JSON string (format name, content version, file format, the config values the table
depends on, rates, gate, quality, direction, and ``sha256``: a checksum of the arrays and
the rest of the metadata). Written atomically (temporary file in the same folder, fsync,
rename), so a daemon never reads a half-written reference.

Reading trusts nothing: the file size, the zip's member names and declared sizes are
checked before anything is inflated, each .npy header (dtype, shape) before its array is
built, then the metadata's types and ranges, the shapes against the metadata, finite
values and the checksum. Anything wrong is one ReferenceFileError naming the file, the
problem and the fix. Limits: docs/reliability.md.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import os
import shutil
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ReferenceFileError, ReferenceMissingError
from ..reference_build import REFERENCE_VERSION, Reference
from ..text import human_bytes, one_line, short_repr
from .files import NotAFile, TooLarge, atomic_writer, read_capped

FORMAT = "bladesonar-reference"
#: Container version: 2 adds ``file_format`` and ``sha256`` to the metadata. Files without
#: ``file_format`` (written before) still load: every zip member carries a CRC-32 that
#: catches a flipped bit, and the full validation below applies to them too.
FILE_FORMAT = 2

#: Largest reference file, and largest total of its members once inflated, bytes. A
#: reference of the largest table the config allows at defaults (256 bins x one PRI of
#: 1297 samples) is 2.7 MB; 64 MiB leaves room for long PRIs and fine tables.
MAX_FILE_BYTES = 64 << 20
MAX_INFLATED_BYTES = 64 << 20
#: Largest metadata member, bytes (the JSON is a few kB).
MAX_META_BYTES = 1 << 20
#: Largest number of phase bins (analysis.phase_bins allows up to 4096).
MAX_BINS = 4096
#: Largest magnitude of a table or mean-pulse value: features of samples in [-1, 1].
MAX_VALUE = 1e6

MEMBERS = ("table.npy", "mean_pulse.npy", "meta.npy")
REMAKE = "make it again with 'bladesonar reference'"


def _canonical(meta: Mapping[str, Any]) -> bytes:
    return json.dumps({k: v for k, v in meta.items() if k != "sha256"},
                      sort_keys=True).encode("utf-8")


def checksum(table: np.ndarray, mean_pulse: np.ndarray, meta: Mapping[str, Any]) -> str:
    """sha256 of the arrays (float64 little-endian, C order, shapes included) and the
    metadata without its own checksum."""
    h = hashlib.sha256()
    for a in (table, mean_pulse):
        a = np.ascontiguousarray(a, dtype="<f8")
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    h.update(_canonical(meta))
    return h.hexdigest()


def reference_bytes(ref: Reference) -> bytes:
    """The .npz bytes of ``ref`` (file format 2, checksummed); pure."""
    table = np.asarray(ref.table, dtype=np.float64)
    mean_pulse = np.asarray(ref.mean_pulse, dtype=np.float64)
    meta = {k: v for k, v in ref.meta.items() if k not in ("id", "sha256")}
    meta["file_format"] = FILE_FORMAT
    meta["sha256"] = checksum(table, mean_pulse, meta)
    buf = io.BytesIO()
    np.savez(buf, table=table, mean_pulse=mean_pulse,
             meta=np.array(json.dumps(meta, sort_keys=True)))
    return buf.getvalue()


def save_reference(ref: Reference, path: str | Path) -> Path:
    """Write ``ref`` to ``path`` atomically; returns the path."""
    write_reference(ref, path)
    return Path(path)


def write_reference(ref: Reference, path: str | Path) -> str:
    """Write ``ref`` to ``path`` atomically (temporary file, fsync, rename, folder fsync:
    after a power loss the file is the old one or the new one, whole); returns the
    sha256 of the bytes written (the daemon's reference id is its first 12 digits)."""
    p = Path(path)
    data = reference_bytes(ref)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        with atomic_writer(p) as f:
            f.write(data)
    except OSError as exc:
        raise ReferenceFileError(f"{p}: cannot be written ({exc.strerror or exc}); choose a "
                                 "writable path with free space") from exc
    return hashlib.sha256(data).hexdigest()


def previous_path(path: str | Path) -> Path:
    """Where the reference replaced or forgotten last is kept: ``<name>.previous``."""
    p = Path(path)
    return p.with_name(p.name + ".previous")


def keep_previous(path: str | Path) -> Path | None:
    """Keep the reference at ``path`` (if any) as :func:`previous_path`, atomically and
    without touching ``path`` itself (a hard link, else a copy, renamed into place);
    returns where it went. To go back: ``mv reference.npz.previous reference.npz``."""
    p = Path(path)
    prev = previous_path(p)
    tmp = p.with_name(f".{p.name}.previous.{os.getpid()}.tmp")
    try:
        try:
            os.link(p, tmp)
        except FileNotFoundError:
            return None
        except OSError:
            shutil.copyfile(p, tmp)
        os.replace(tmp, prev)
        _fsync_dir(p.parent)
    except FileNotFoundError:
        return None
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise ReferenceFileError(f"{prev}: cannot keep the previous reference there "
                                 f"({exc.strerror or exc}); check the state folder's "
                                 "permissions and free space") from exc
    return prev


def forget_reference(path: str | Path) -> Path | None:
    """Remove the reference at ``path``, kept as :func:`previous_path` (returned; None if
    there was none). Durable: the folder is fsynced."""
    p = Path(path)
    prev = keep_previous(p)
    try:
        os.unlink(p)
    except FileNotFoundError:
        return prev
    except OSError as exc:
        raise ReferenceFileError(f"{p}: cannot be removed ({exc.strerror or exc}); check "
                                 "the state folder's permissions") from exc
    _fsync_dir(p.parent)
    return prev


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder if str(folder) else ".", os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# -- reading -----------------------------------------------------------------------------


class _Bad(Exception):
    """A validation failure inside the parser (becomes one ReferenceFileError)."""


def _read_members(data: bytes) -> dict[str, bytes]:
    """The three members' bytes, with names, count, method and declared sizes checked
    before any is inflated, and each read no further than its declared size."""
    zf = zipfile.ZipFile(io.BytesIO(data))
    infos = zf.infolist()
    names = [i.filename for i in infos]
    if sorted(names) != sorted(MEMBERS):
        raise _Bad(f"holds {short_repr(names)}, not the arrays {', '.join(MEMBERS)}")
    total = 0
    for i in infos:
        if i.flag_bits & 0x1:
            raise _Bad(f"member {i.filename} is encrypted")
        if i.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise _Bad(f"member {i.filename} uses compression method {i.compress_type}")
        limit = MAX_META_BYTES if i.filename == "meta.npy" else MAX_INFLATED_BYTES
        if i.file_size > limit:
            raise _Bad(f"member {i.filename} declares {human_bytes(i.file_size)}, more than "
                       f"the {human_bytes(limit)} a reference may hold")
        total += i.file_size
    if total > MAX_INFLATED_BYTES:
        raise _Bad(f"members declare {human_bytes(total)} in all, more than the "
                   f"{human_bytes(MAX_INFLATED_BYTES)} a reference may hold")
    out = {}
    for i in infos:
        with zf.open(i) as f:
            raw = f.read(i.file_size + 1)   # ZipExtFile checks the CRC-32 at the end
        if len(raw) != i.file_size:
            raise _Bad(f"member {i.filename} holds {len(raw)} bytes, its header says "
                       f"{i.file_size}")
        out[i.filename] = raw
    return out


def _npy(raw: bytes, name: str, *, kind: str) -> np.ndarray:
    """An array from .npy bytes, its header checked before the data is touched: no
    objects (pickles), the expected dtype kind, a size that matches the bytes."""
    bio = io.BytesIO(raw)
    version = np.lib.format.read_magic(bio)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(bio)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(bio)
    else:
        raise _Bad(f"{name}: .npy version {version} is not supported")
    if dtype.hasobject or dtype.kind != kind or (kind == "f" and dtype.itemsize != 8):
        want = "float64" if kind == "f" else "a text string"
        raise _Bad(f"{name} has dtype {dtype}, not {want}")
    count = math.prod(shape)
    offset = bio.tell()
    if count * dtype.itemsize != len(raw) - offset:
        raise _Bad(f"{name} declares shape {shape} ({count * dtype.itemsize} bytes) but "
                   f"holds {len(raw) - offset}")
    a = np.frombuffer(raw, dtype=dtype, count=count, offset=offset)
    a = a.reshape(shape, order="F" if fortran else "C")
    if kind == "f" and dtype == np.dtype("<f8") and not fortran:
        return a    # a read-only view of the member's bytes: no second copy
    return np.array(a, dtype=np.float64) if kind == "f" else a


def _num(meta: dict[str, Any], key: str, *, lo: float = -math.inf, hi: float = math.inf,
         lo_open: bool = False, integer: bool = False, optional: bool = False) -> Any:
    if key not in meta and optional:
        return None
    v: Any = meta.get(key)   # a file's value: checked here
    ok_type = isinstance(v, int) if integer else isinstance(v, (int, float))
    if isinstance(v, bool) or not ok_type or not math.isfinite(v) or v < lo or v > hi \
            or (lo_open and v == lo):
        what = "an integer" if integer else "a finite number"
        rng = f" {'above' if lo_open else 'from'} {lo:g} to {hi:g}" if math.isfinite(hi) \
            else (f" above {lo:g}" if lo_open else (f" of at least {lo:g}"
                                                    if math.isfinite(lo) else ""))
        raise _Bad(f"metadata {key} = {short_repr(v)}, not {what}{rng}")
    return v


def _check_meta(meta: Any) -> None:  # noqa: C901  a flat list, one check per metadata key
    """Types and ranges of every metadata value the analysis reads."""
    from .. import config as config_mod
    from ..dsp.gate import max_gate_stop
    from ..errors import ConfigError
    from ..reference_build import depends_on

    if not isinstance(meta, dict):
        raise _Bad(f"metadata is {type(meta).__name__}, not a JSON object")
    if meta.get("format") != FORMAT:
        raise _Bad(f"format {short_repr(meta.get('format'))}, not {FORMAT!r}; it is not a "
                   "bladesonar reference file")
    if meta.get("version") != REFERENCE_VERSION or isinstance(meta.get("version"), bool):
        raise ReferenceFileError(
            f"reference format version {short_repr(meta.get('version'))}, this bladesonar "
            f"reads version {REFERENCE_VERSION}; make the reference again")
    ff = meta.get("file_format", 1)
    if ff not in (1, FILE_FORMAT) or isinstance(ff, bool):
        raise ReferenceFileError(f"file format {short_repr(ff)}, this bladesonar reads 1 to "
                                 f"{FILE_FORMAT}; make the reference again with this "
                                 "version")
    dep = meta.get("depends")
    want = set(depends_on(config_mod.Config()))
    if not isinstance(dep, dict) or set(dep) != want:
        raise _Bad(f"metadata depends = {short_repr(dep)} does not list the config values "
                   "the table depends on")
    nested: dict[str, dict[str, Any]] = {}
    for key, value in dep.items():
        sec, name = key.split(".", 1)
        nested.setdefault(sec, {})[name] = value
    try:
        config_mod.from_mapping(nested)
    except ConfigError as exc:
        raise _Bad(f"metadata depends: {exc}") from None
    pri = dep["waveform.pri_samples"]
    gs = meta.get("gate_samples")
    if not (isinstance(gs, list) and len(gs) == 2
            and all(isinstance(g, int) and not isinstance(g, bool) for g in gs)
            and 0 <= gs[0] < gs[1] <= max_gate_stop(pri)):
        raise _Bad(f"metadata gate_samples = {short_repr(gs)}, not [start, stop] with "
                   f"0 <= start < stop <= {max_gate_stop(pri)}")
    gm = meta.get("gate_m")
    if not (isinstance(gm, list) and len(gm) == 2 and all(
            isinstance(g, (int, float)) and not isinstance(g, bool) and math.isfinite(g)
            for g in gm)):
        raise _Bad(f"metadata gate_m = {short_repr(gm)}, not two ranges in metres")
    _num(meta, "cycles_per_pulse", lo=0.0, hi=0.5, lo_open=True)
    for key in ("rate_hz", "blade_rate_hz", "prf_hz"):
        _num(meta, key, lo=0.0, lo_open=True, optional=key != "rate_hz")
    for key in ("rpm", "periods_folded", "quality", "line_snr", "explained_lines",
                "min_bin_weight", "direction_contrast", "match_share",
                "astray_share"):
        _num(meta, key, optional=True)
    for key in ("pulses", "used_pulses", "dropped_pulses"):
        _num(meta, key, lo=0, integer=True, optional=True)
    _num(meta, "phase_bins", lo=1, hi=MAX_BINS, integer=True)
    if meta.get("direction") not in ("cw", "ccw", "unknown"):
        raise _Bad(f"metadata direction = {short_repr(meta.get('direction'))}, not cw, ccw "
                   "or unknown")
    tr = meta.get("target_range_m")
    if tr is not None:
        _num(meta, "target_range_m", lo=0.0)
    tw = meta.get("twin_bins")
    bins = meta["phase_bins"]
    if tw is not None and not (isinstance(tw, list) and len(tw) == bins and all(
            isinstance(t, int) and not isinstance(t, bool) and -1 <= t < bins for t in tw)):
        raise _Bad(f"metadata twin_bins = {short_repr(tw)}, not a list of {bins} bins "
                   f"(-1 or 0 to {bins - 1})")
    w = meta.get("warnings", [])
    if not (isinstance(w, list) and all(isinstance(s, str) for s in w)):
        raise _Bad(f"metadata warnings = {short_repr(w)}, not a list of text")


def _check_arrays(table: np.ndarray, mean_pulse: np.ndarray, meta: dict[str, Any]) -> None:
    bins = meta["phase_bins"]
    length = meta["gate_samples"][1] - meta["gate_samples"][0]
    if table.shape != (bins, length) or mean_pulse.shape != (length,):
        raise _Bad(f"table {table.shape} and mean pulse {mean_pulse.shape} do not match the "
                   f"metadata ({bins} phase bins, gate of {length} samples)")
    for name, a in (("table", table), ("mean pulse", mean_pulse)):
        if not np.all(np.isfinite(a)):
            raise _Bad(f"{name} holds NaN or infinite values")
        if a.size and float(np.max(np.abs(a))) > MAX_VALUE:
            raise _Bad(f"{name} holds values beyond {MAX_VALUE:g}")
    if not np.any(table):
        raise _Bad("table is all zero")


def parse_reference(data: bytes, name: str = "reference") -> Reference:
    """A validated Reference from the bytes of a reference file (pure; ``name`` is the
    file's name for messages). Raises ReferenceFileError only."""
    if len(data) > MAX_FILE_BYTES:
        raise ReferenceFileError(f"{name}: {human_bytes(len(data))}, larger than the "
                                 f"{human_bytes(MAX_FILE_BYTES)} a reference may be; {REMAKE}")
    try:
        members = _read_members(data)
        table = _npy(members["table.npy"], "table", kind="f")
        mean_pulse = _npy(members["mean_pulse.npy"], "mean_pulse", kind="f")
        meta_arr = _npy(members["meta.npy"], "meta", kind="U")
        if meta_arr.shape != ():
            raise _Bad(f"meta has shape {meta_arr.shape}, not one text string")
        meta = json.loads(str(meta_arr[()]))
        _check_meta(meta)
        _check_arrays(table, mean_pulse, meta)
        if "file_format" in meta:
            if meta.get("sha256") != checksum(table, mean_pulse, meta):
                raise _Bad("checksum does not match its contents (damaged or edited)")
    except ReferenceFileError as exc:
        raise ReferenceFileError(f"{name}: {exc}") from None
    except _Bad as exc:
        raise ReferenceFileError(f"{name}: corrupt reference: {exc}; {REMAKE}") from None
    except (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, EOFError, OSError,
            ValueError, KeyError, IndexError, TypeError, OverflowError, RecursionError,
            NotImplementedError, RuntimeError, UnicodeError, MemoryError) as exc:
        why = one_line(str(exc) or type(exc).__name__)
        raise ReferenceFileError(f"{name}: not a bladesonar reference file, or a damaged one "
                                 f"({type(exc).__name__}: {why}); {REMAKE}") from None
    return Reference(table=table, mean_pulse=mean_pulse, meta=meta)


def read_reference(path: str | Path) -> tuple[Reference, str]:
    """The validated reference in ``path`` and the sha256 of the bytes it was read from
    (the file is read once, so the id always belongs to the reference returned)."""
    p = Path(path)
    try:
        data = read_capped(p, MAX_FILE_BYTES)
    except FileNotFoundError:
        raise ReferenceMissingError(f"{p}: no such reference file; make one with 'bladesonar "
                                 "reference --config CFG --direction cw|ccw|unknown --out "
                                 f"{p.name} RECORDING.wav'") from None
    except PermissionError as exc:
        raise ReferenceFileError(
            f"{p}: cannot be read ({exc.strerror}); it belongs to another user: record it as "
            "the daemon's user (sudo -u bladesonar bladesonar reference --live ...) or chown "
            "it to that user") from None
    except TooLarge:
        raise ReferenceFileError(f"{p}: larger than the {human_bytes(MAX_FILE_BYTES)} a "
                                 f"reference may be; {REMAKE}") from None
    except NotAFile as exc:
        raise ReferenceFileError(f"{p}: {exc}; give the path of a reference .npz "
                                 "file") from None
    except OSError as exc:
        raise ReferenceFileError(f"{p}: cannot be read ({exc.strerror or exc}); check the "
                                 "path and the disk") from None
    return parse_reference(data, str(p)), hashlib.sha256(data).hexdigest()


def load_reference(path: str | Path) -> Reference:
    """Read and validate a reference file (not against the config: see
    ``reference_build.check_compatible``)."""
    return read_reference(path)[0]
