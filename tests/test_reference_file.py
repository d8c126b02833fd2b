"""Reference files: format 2 (checksummed) round trip, format-1 files still load, an edit
that keeps the zip CRCs valid is caught by the checksum, newer formats are refused."""

from __future__ import annotations

import hashlib
import io
import json

import numpy as np
import pytest

from bladesonar import config
from bladesonar.errors import ReferenceFileError, ReferenceMissingError
from bladesonar.io.reference import (
    FILE_FORMAT,
    load_reference,
    parse_reference,
    read_reference,
    save_reference,
)
from bladesonar.io.scene_file import load_scene
from bladesonar.reference_build import build_reference
from bladesonar.sim.render import simulate
from bladesonar.sim.schedule import Schedule
from loopback import SCENE


@pytest.fixture(scope="module")
def ref():
    cfg = config.Config()
    x, _ = simulate(load_scene(SCENE), cfg, 8.0, schedule=Schedule.constant(0.45, "ccw"),
                    snr_db=20.0, seed=5)
    return build_reference(x, cfg, "ccw")


def _npz(table, mean_pulse, meta) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, table=table, mean_pulse=mean_pulse, meta=np.array(json.dumps(meta)))
    return buf.getvalue()


def test_round_trip_is_format_2_with_a_checksum_and_the_id_of_its_bytes(ref, tmp_path):
    p = save_reference(ref, tmp_path / "r.npz")
    got, digest = read_reference(p)
    assert np.array_equal(got.table, ref.table)
    assert np.array_equal(got.mean_pulse, ref.mean_pulse)
    assert got.meta["file_format"] == FILE_FORMAT == 2 and len(got.meta["sha256"]) == 64
    assert {k: v for k, v in got.meta.items() if k not in ("file_format", "sha256")} == \
        json.loads(json.dumps(ref.meta))
    assert digest == hashlib.sha256(p.read_bytes()).hexdigest()
    assert [q.name for q in tmp_path.iterdir()] == ["r.npz"]     # no temporary left


def test_format_1_files_without_checksum_still_load(ref, tmp_path):
    """What 'bladesonar reference' wrote before format 2 (same arrays, no file_format)."""
    p = tmp_path / "old.npz"
    p.write_bytes(_npz(ref.table, ref.mean_pulse, ref.meta))
    got = load_reference(p)
    assert "file_format" not in got.meta and np.array_equal(got.table, ref.table)


def test_format_1_files_get_the_full_validation(ref):
    t = ref.table.copy()
    t[2, 3] = np.nan
    with pytest.raises(ReferenceFileError, match="NaN"):
        parse_reference(_npz(t, ref.mean_pulse, ref.meta), "old.npz")


def test_an_edit_with_valid_zip_crcs_is_caught_by_the_checksum(ref, tmp_path):
    p = save_reference(ref, tmp_path / "r.npz")
    with np.load(p) as z:
        meta = json.loads(str(z["meta"]))
    meta["rate_hz"] = 0.9          # plausible, so only the checksum can tell
    with pytest.raises(ReferenceFileError, match="checksum"):
        parse_reference(_npz(ref.table, ref.mean_pulse, meta), "edited.npz")


def test_a_newer_file_format_is_refused_by_name(ref):
    meta = dict(ref.meta, file_format=3, sha256="0" * 64)
    with pytest.raises(ReferenceFileError, match="file format 3"):
        parse_reference(_npz(ref.table, ref.mean_pulse, meta), "new.npz")


def test_missing_is_its_own_error_and_an_unwritable_path_one_line(ref, tmp_path):
    with pytest.raises(ReferenceMissingError):
        load_reference(tmp_path / "none.npz")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ReferenceFileError, match="cannot be written") as e:
        save_reference(ref, blocker / "r.npz")
    assert "\n" not in str(e.value)


def test_twin_bins_round_trip_and_a_bad_list_is_refused_by_name(ref, tmp_path):
    """A glint scene's reference names each bin's look-alike (fingerprint.twin_bins);
    a list that does not fit the table is refused with the value and its form."""
    bins = ref.meta["phase_bins"]
    twins = [-1] * bins
    twins[2] = bins - 2
    got, _ = read_reference(save_reference(
        type(ref)(ref.table, ref.mean_pulse, dict(ref.meta, twin_bins=twins)),
        tmp_path / "t.npz"))
    assert got.meta["twin_bins"] == twins
    for bad in ([0] * (bins - 1), [bins] + [-1] * (bins - 1), [True] + [-1] * (bins - 1)):
        with pytest.raises(ReferenceFileError, match=f"twin_bins .*not a list of {bins}"):
            parse_reference(_npz(ref.table, ref.mean_pulse, dict(ref.meta, twin_bins=bad)),
                            "bad.npz")
