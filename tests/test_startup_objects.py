"""A long-lived process freezes its startup objects once (`app.startup_objects`): what is
garbage then is collected first, and a later call freezes nothing more."""

from __future__ import annotations

import json
import subprocess
import sys

from app import startup_objects

PROBE = f"""
import gc, json, weakref
import {startup_objects.__name__} as startup_objects
class Node:
    pass
a, b = Node(), Node()
a.other, b.other = b, a  # a cycle that only the collector frees
gone = weakref.ref(a)
del a, b
before = gc.get_freeze_count()
startup_objects.freeze()
first = gc.get_freeze_count()
kept = [[] for _ in range(1000)]
startup_objects.freeze()
print(json.dumps({{"before": before, "first": first, "second": gc.get_freeze_count(),
                   "garbage_collected": gone() is None}}))
"""


def test_startup_objects_are_frozen_once_after_the_garbage_is_collected():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         check=True, timeout=60)
    counts = json.loads(out.stdout)
    assert counts["before"] == 0 and counts["first"] > 1000
    assert counts["second"] == counts["first"]
    assert counts["garbage_collected"]
