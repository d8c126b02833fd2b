"""Reference files: the angular table and its metadata in one versioned .npz.

Layout: arrays ``table`` (B, L) and ``mean_pulse`` (L,), and ``meta`` holding one JSON
string (format name, version, the config values the table depends on, rates, gate,
quality, direction). Written atomically (temporary file in the same folder, fsync,
rename), so a daemon never reads a half-written reference.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from ..analysis import REFERENCE_VERSION, Reference
from ..errors import ReferenceFileError

FORMAT = "bladesonar-reference"


def save_reference(ref: Reference, path: str | Path) -> Path:
    """Write ``ref`` to ``path`` atomically; returns the path."""
    p = Path(path)
    buf = io.BytesIO()
    np.savez(buf, table=np.asarray(ref.table, dtype=np.float64),
             mean_pulse=np.asarray(ref.mean_pulse, dtype=np.float64),
             meta=np.array(json.dumps(ref.meta, sort_keys=True)))
    data = buf.getvalue()
    folder = p.parent if str(p.parent) else Path(".")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=folder)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, p)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
        try:
            dfd = os.open(folder, os.O_RDONLY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
        except OSError:
            pass
    except OSError as exc:
        raise ReferenceFileError(f"{p}: cannot be written ({exc.strerror}); choose a "
                                 "writable path") from exc
    return p


def load_reference(path: str | Path) -> Reference:
    """Read a reference file, checking its format and version (not the config: see
    ``analysis.check_compatible``)."""
    p = Path(path)
    if not p.is_file():
        raise ReferenceFileError(f"{p}: no such reference file; make one with 'bladesonar "
                                 "reference --config CFG --direction cw|ccw|unknown --out "
                                 f"{p.name} RECORDING.wav'")
    try:
        with np.load(p, allow_pickle=False) as z:
            table = np.array(z["table"], dtype=np.float64)
            mean_pulse = np.array(z["mean_pulse"], dtype=np.float64)
            meta = json.loads(str(z["meta"]))
    except PermissionError as exc:
        raise ReferenceFileError(
            f"{p}: cannot be read ({exc.strerror}); it belongs to another user: record it as "
            "the daemon's user (sudo -u bladesonar bladesonar reference --live ...) or chown "
            "it to that user") from exc
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
        raise ReferenceFileError(f"{p}: not a bladesonar reference file ({exc}); make it "
                                 "again with 'bladesonar reference'") from exc
    if meta.get("format") != FORMAT:
        raise ReferenceFileError(f"{p}: not a bladesonar reference file (format "
                                 f"{meta.get('format')!r})")
    if meta.get("version") != REFERENCE_VERSION:
        raise ReferenceFileError(f"{p}: reference format version {meta.get('version')!r}, "
                                 f"this bladesonar reads version {REFERENCE_VERSION}; make "
                                 "the reference again")
    if table.ndim != 2 or mean_pulse.shape != (table.shape[1],):
        raise ReferenceFileError(f"{p}: corrupt reference (table {table.shape}, mean pulse "
                                 f"{mean_pulse.shape})")
    return Reference(table=table, mean_pulse=mean_pulse, meta=meta)
