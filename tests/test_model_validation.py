"""Every validation rule of planner.model.Robot: the error's location and exact message.

Each case edits a valid two-link robot document in one place and expects exactly one
error. Model-level rules (a wave that does not fit its link, no active joint) are
reported at the enclosing model with the field named at the start of the message.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
from pydantic import ValidationError

from planner.model import MAX_LINKS, Robot

Doc = dict


def valid() -> Doc:
    return {"links": [
        {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
        {"length": 0.4, "mass": 0.5, "inertia": 0.005, "joint": "active",
         "wave": {"amplitude": 0.05, "frequency": 3.0, "phase": 0.3}},
    ], "gravity": 9.81, "rotational_inertia": "cumulative"}


def edit(path: tuple, value) -> Callable[[Doc], Doc]:
    """A change setting doc[path] = value."""
    def apply(doc: Doc) -> Doc:
        node = doc
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
        return doc
    return apply


def drop(path: tuple) -> Callable[[Doc], Doc]:
    def apply(doc: Doc) -> Doc:
        node = doc
        for key in path[:-1]:
            node = node[key]
        del node[path[-1]]
        return doc
    return apply


GT0 = "Input should be greater than 0"
GE0 = "Input should be greater than or equal to 0"
FINITE = "Input should be a finite number"
EXTRA = "Extra inputs are not permitted"

CASES = {
    "zero length": (edit(("links", 0, "length"), 0.0), ("links", 0, "length"), GT0),
    "negative length": (edit(("links", 1, "length"), -0.4), ("links", 1, "length"), GT0),
    "zero mass": (edit(("links", 1, "mass"), 0.0), ("links", 1, "mass"), GT0),
    "negative mass": (edit(("links", 0, "mass"), -1.0), ("links", 0, "mass"), GT0),
    "negative inertia": (edit(("links", 0, "inertia"), -0.01), ("links", 0, "inertia"), GE0),
    "negative amplitude": (edit(("links", 1, "wave", "amplitude"), -0.05),
                           ("links", 1, "wave", "amplitude"), GE0),
    "negative frequency": (edit(("links", 1, "wave", "frequency"), -3.0),
                           ("links", 1, "wave", "frequency"), GE0),
    "negative gravity": (edit(("gravity",), -9.81), ("gravity",), GE0),
    "amplitude equal to length": (
        edit(("links", 1, "wave", "amplitude"), 0.4), ("links", 1),
        "Value error, wave.amplitude: must be smaller than the link length (0.4 >= 0.4)"),
    "amplitude above length": (
        edit(("links", 1, "wave", "amplitude"), 0.45), ("links", 1),
        "Value error, wave.amplitude: must be smaller than the link length (0.45 >= 0.4)"),
    "nan length": (edit(("links", 0, "length"), math.nan), ("links", 0, "length"), FINITE),
    "inf mass": (edit(("links", 1, "mass"), math.inf), ("links", 1, "mass"), FINITE),
    "-inf inertia": (edit(("links", 0, "inertia"), -math.inf), ("links", 0, "inertia"), FINITE),
    "nan amplitude": (edit(("links", 1, "wave", "amplitude"), math.nan),
                      ("links", 1, "wave", "amplitude"), FINITE),
    "inf frequency": (edit(("links", 1, "wave", "frequency"), math.inf),
                      ("links", 1, "wave", "frequency"), FINITE),
    "nan phase": (edit(("links", 1, "wave", "phase"), math.nan), ("links", 1, "wave", "phase"), FINITE),
    "inf gravity": (edit(("gravity",), math.inf), ("gravity",), FINITE),
    "nan as a string": (edit(("links", 0, "length"), "nan"), ("links", 0, "length"), FINITE),
    "wave on a passive joint": (
        edit(("links", 0, "wave"), {"amplitude": 0.05, "frequency": 2.0}), ("links", 0),
        "Value error, wave: a passive joint cannot carry a wave"),
    "no active joint": (lambda doc: edit(("links", 1, "joint"), "passive")(drop(("links", 1, "wave"))(doc)), (),
                        "Value error, links: at least one joint must be active"),
    "unknown joint kind": (edit(("links", 1, "joint"), "free"), ("links", 1, "joint"),
                           "Input should be 'passive' or 'active'"),
    "more than 8 links": (
        lambda doc: {**doc, "links": doc["links"] * 4 + doc["links"][:1]}, ("links",),
        f"List should have at most {MAX_LINKS} items after validation, not {MAX_LINKS + 1}"),
    "zero links": (edit(("links",), []), ("links",),
                   "List should have at least 1 item after validation, not 0"),
    "no links field": (drop(("links",)), ("links",), "Field required"),
    "no joint field": (drop(("links", 0, "joint")), ("links", 0, "joint"), "Field required"),
    "unknown robot field": (edit(("colour",), "red"), ("colour",), EXTRA),
    "unknown link field": (edit(("links", 0, "width"), 0.05), ("links", 0, "width"), EXTRA),
    "unknown wave field": (edit(("links", 1, "wave", "shape"), "square"),
                           ("links", 1, "wave", "shape"), EXTRA),
    "unknown rotational_inertia": (edit(("rotational_inertia",), "relative"), ("rotational_inertia",),
                                   "Input should be 'cumulative' or 'absolute'"),
}


def test_the_base_document_is_valid():
    robot = Robot.model_validate(valid())
    assert (robot.n, robot.active, robot.passive) == (2, [1], [0])


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_rule_reports_location_and_message(case):
    change, loc, msg = CASES[case]
    with pytest.raises(ValidationError) as info:
        Robot.model_validate(change(valid()))
    assert [(e["loc"], e["msg"]) for e in info.value.errors()] == [(loc, msg)]


@pytest.mark.parametrize("n", [1, MAX_LINKS])
def test_size_limits_are_inclusive(n):
    links = [{"length": 0.3, "mass": 0.2, "joint": "active"}] * n
    assert Robot.model_validate({"links": links}).n == n


def test_amplitude_just_below_length_is_accepted():
    doc = edit(("links", 1, "wave", "amplitude"), 0.4 * (1 - 1e-12))(valid())
    assert Robot.model_validate(doc).links[1].wavy


def test_defaults():
    robot = Robot.model_validate({"links": [{"length": 1.0, "mass": 1.0, "joint": "active",
                                             "wave": {"amplitude": 0.1, "frequency": 2.0}}]})
    assert (robot.gravity, robot.rotational_inertia) == (0.0, "cumulative")
    assert (robot.links[0].inertia, robot.links[0].wave.phase) == (0.0, 0.0)


def test_robots_are_immutable():
    robot = Robot.model_validate(valid())
    with pytest.raises(ValidationError) as info:
        robot.gravity = 1.0
    assert [(e["loc"], e["msg"]) for e in info.value.errors()] == [(("gravity",), "Instance is frozen")]
