"""The store's JSON text (`app.store.json_text`) reads back as the standard library's
would, to the last bit of every number, and holds no NaN or Infinity."""

from __future__ import annotations

import json
import math

import numpy as np

from app.store import json_text


def test_a_value_reads_back_exactly_as_the_standard_librarys_text_does():
    rng = np.random.default_rng(7)
    value = {"t": rng.normal(size=500).tolist(), "tiny": [5e-324, 1e-300, -0.0, 1.0e22],
             "q": rng.normal(scale=1e6, size=(40, 4)).tolist(), "n": 2**62, "ok": True,
             "none": None, "text": "σ_min ≥ 0 \"quoted\"\n", "nested": {"a": [[], {}]}}
    ours = json_text.dumps(value)
    assert json.loads(ours) == value == json_text.loads(json.dumps(value))
    assert json_text.loads(ours) == value
    assert all(math.copysign(1, a) == math.copysign(1, b)
               for a, b in zip(json_text.loads(ours)["tiny"], value["tiny"], strict=True))


def test_numbers_that_are_not_finite_are_written_as_null_and_earlier_text_still_reads():
    assert json.loads(json_text.dumps({"a": math.nan, "b": [math.inf, -math.inf, 1.5]})) \
        == {"a": None, "b": [None, None, 1.5]}
    earlier = json_text.loads('{"a": NaN, "b": Infinity, "c": -Infinity}')
    assert math.isnan(earlier["a"]) and earlier["b"] == math.inf and earlier["c"] == -math.inf
