"""io/truth.read_truth: a truth file is a JSON object; anything else is a ValueError naming
the file (which ``plot track --truth`` turns into one error line), not a list that fails
later with a TypeError and a traceback."""

from __future__ import annotations

import json

import pytest

from bladesonar.io.truth import read_truth


@pytest.mark.parametrize("text", ["[1, 2]", "\"meta\"", "3", "null"])
def test_json_that_is_not_an_object_is_refused_naming_the_file(tmp_path, text):
    p = tmp_path / "t.json"
    p.write_text(text)
    with pytest.raises(ValueError, match="t.json: holds a JSON .*, not a truth object"):
        read_truth(p)


def test_an_object_is_read_as_written(tmp_path):
    truth = {"meta": {"schedule": "0:0.45ccw"}, "pulses": [{"k": 0, "angle": 0.5}]}
    p = tmp_path / "t.json"
    p.write_text(json.dumps(truth))
    assert read_truth(p) == truth
