"""Every validation rule of planner.model.Robot: the error's location and exact message.

Each case edits a valid two-link robot document in one place and expects exactly one
error. Rules that read other fields are reported at the field they check: a wave that
does not fit its link at the link's `wave` (naming `amplitude` at the start of the
message), a robot without an active joint at `links`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from pydantic import ValidationError

from planner.dynamics import Dynamics
from planner.model import (
    MAX_FREQUENCY,
    MAX_GRAVITY,
    MAX_INERTIA,
    MAX_LENGTH,
    MAX_LINKS,
    MAX_MASS,
    MAX_PHASE,
    MIN_LENGTH,
    MIN_MASS,
    Robot,
    Wave,
)

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


GE0 = "Input should be greater than or equal to 0"
GE_LENGTH = "Input should be greater than or equal to 0.0001"
LE_LENGTH = "Input should be less than or equal to 1000"
GE_MASS = "Input should be greater than or equal to 0.000001"
LE_MASS = "Input should be less than or equal to 1000000"
FINITE = "Input should be a finite number"
EXTRA = "Extra inputs are not permitted"

CASES = {
    "zero length": (edit(("links", 0, "length"), 0.0), ("links", 0, "length"), GE_LENGTH),
    "negative length": (edit(("links", 1, "length"), -0.4), ("links", 1, "length"), GE_LENGTH),
    "length below 0.1 mm": (edit(("links", 0, "length"), 0.99e-4), ("links", 0, "length"),
                            GE_LENGTH),
    "tiny length": (edit(("links", 0, "length"), 1e-200), ("links", 0, "length"), GE_LENGTH),
    "length above 1 km": (edit(("links", 0, "length"), 1000.1), ("links", 0, "length"), LE_LENGTH),
    "huge length": (edit(("links", 1, "length"), 1e200), ("links", 1, "length"), LE_LENGTH),
    "zero mass": (edit(("links", 1, "mass"), 0.0), ("links", 1, "mass"), GE_MASS),
    "negative mass": (edit(("links", 0, "mass"), -1.0), ("links", 0, "mass"), GE_MASS),
    "tiny mass": (edit(("links", 0, "mass"), 1e-200), ("links", 0, "mass"), GE_MASS),
    "huge mass": (edit(("links", 1, "mass"), 1e200), ("links", 1, "mass"), LE_MASS),
    "negative inertia": (edit(("links", 0, "inertia"), -0.01), ("links", 0, "inertia"), GE0),
    "huge inertia": (edit(("links", 0, "inertia"), 1.01e6), ("links", 0, "inertia"),
                     "Input should be less than or equal to 1000000"),
    "negative amplitude": (edit(("links", 1, "wave", "amplitude"), -0.05),
                           ("links", 1, "wave", "amplitude"), GE0),
    "negative frequency": (edit(("links", 1, "wave", "frequency"), -3.0),
                           ("links", 1, "wave", "frequency"), GE0),
    "frequency above 100": (edit(("links", 1, "wave", "frequency"), 100.5),
                            ("links", 1, "wave", "frequency"),
                            "Input should be less than or equal to 100"),
    "phase above 1000": (edit(("links", 1, "wave", "phase"), 1000.5), ("links", 1, "wave", "phase"),
                         "Input should be less than or equal to 1000"),
    "phase below -1000": (edit(("links", 1, "wave", "phase"), -1e200),
                          ("links", 1, "wave", "phase"),
                          "Input should be greater than or equal to -1000"),
    "negative gravity": (edit(("gravity",), -9.81), ("gravity",), GE0),
    "gravity above 1000": (edit(("gravity",), 1e4), ("gravity",),
                           "Input should be less than or equal to 1000"),
    "amplitude equal to length": (
        edit(("links", 1, "wave", "amplitude"), 0.4), ("links", 1, "wave"),
        "Value error, amplitude: must be smaller than the link length (0.4 >= 0.4)"),
    "amplitude above length": (
        edit(("links", 1, "wave", "amplitude"), 0.45), ("links", 1, "wave"),
        "Value error, amplitude: must be smaller than the link length (0.45 >= 0.4)"),
    "amplitude above an invalid length": (
        edit(("links", 1, "length"), 1e-5), ("links", 1, "length"), GE_LENGTH),
    "nan length": (edit(("links", 0, "length"), math.nan), ("links", 0, "length"), FINITE),
    "inf mass": (edit(("links", 1, "mass"), math.inf), ("links", 1, "mass"), FINITE),
    "-inf inertia": (edit(("links", 0, "inertia"), -math.inf), ("links", 0, "inertia"), FINITE),
    "nan amplitude": (edit(("links", 1, "wave", "amplitude"), math.nan),
                      ("links", 1, "wave", "amplitude"), FINITE),
    "inf frequency": (edit(("links", 1, "wave", "frequency"), math.inf),
                      ("links", 1, "wave", "frequency"), FINITE),
    "nan phase": (edit(("links", 1, "wave", "phase"), math.nan), ("links", 1, "wave", "phase"),
                  FINITE),
    "inf gravity": (edit(("gravity",), math.inf), ("gravity",), FINITE),
    "nan as a string": (edit(("links", 0, "length"), "nan"), ("links", 0, "length"),
                        "Input should be a valid number"),
    "wave on a passive joint": (
        edit(("links", 0, "wave"), {"amplitude": 0.05, "frequency": 2.0}), ("links", 0, "wave"),
        "Value error, a passive joint cannot carry a wave"),
    "wave on an unknown joint kind": (edit(("links", 1, "joint"), "free"), ("links", 1, "joint"),
                                      "Input should be 'passive' or 'active'"),
    "no active joint": (lambda doc: edit(("links", 1, "joint"),
                                         "passive")(drop(("links", 1, "wave"))(doc)),
                        ("links",), "Value error, at least one joint must be active"),
    "unknown joint kind": (lambda doc: edit(("links", 1, "joint"),
                                            "free")(drop(("links", 1, "wave"))(doc)),
                           ("links", 1, "joint"), "Input should be 'passive' or 'active'"),
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
    "unknown rotational_inertia": (edit(("rotational_inertia",), "relative"),
                                   ("rotational_inertia",),
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


BOUNDS = {"length": (MIN_LENGTH, MAX_LENGTH), "mass": (MIN_MASS, MAX_MASS),
          "inertia": (0.0, MAX_INERTIA)}


@pytest.mark.parametrize("field", BOUNDS)
@pytest.mark.parametrize("end", [0, 1], ids=["lower", "upper"])
def test_link_bounds_are_inclusive(field, end):
    doc = drop(("links", 1, "wave"))(edit(("links", 1, field), BOUNDS[field][end])(valid()))
    assert getattr(Robot.model_validate(doc).links[1], field) == BOUNDS[field][end]


def test_wave_and_gravity_bounds_are_inclusive():
    doc = valid()
    doc["links"][1]["wave"].update(frequency=MAX_FREQUENCY, phase=-MAX_PHASE)
    doc["gravity"] = MAX_GRAVITY
    robot = Robot.model_validate(doc)
    assert (robot.links[1].wave.frequency, robot.links[1].wave.phase, robot.gravity) == (
        MAX_FREQUENCY, -MAX_PHASE, MAX_GRAVITY)


def test_the_stress_ranges_are_valid():
    """Lengths 1e-2..10 m, mass ratios 1e-3..1e3 and frequencies up to 20 are accepted."""
    links = [{"length": length, "mass": mass, "inertia": 1e-3, "joint": "active",
              "wave": {"amplitude": 0.9 * length, "frequency": 20.0, "phase": -3.0}}
             for length, mass in [(1e-2, 1e-3), (10.0, 1e3), (1e-2, 1e3), (10.0, 1e-3)]]
    links[0] = {**links[0], "joint": "passive", "wave": None}
    assert Robot.model_validate({"links": links, "gravity": 9.81}).n == 4


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
    errors = [(e["loc"], e["msg"]) for e in info.value.errors()]
    assert errors == [(("gravity",), "Instance is frozen")]


def test_frequency_counts_periods_per_turn_as_documented():
    """The schema says n periods per full turn; the tip radius of one link repeats n times."""
    description = Wave.model_json_schema()["properties"]["frequency"]["description"]
    assert description == "n [-], periods of the wave per full turn (2 pi rad) of the joint angle"
    n = 3.0
    robot = Robot.model_validate({"links": [{"length": 1.0, "mass": 1.0, "joint": "active",
                                             "wave": {"amplitude": 0.2, "frequency": n}}]})
    dyn, q = Dynamics(robot), np.linspace(0.0, 2 * np.pi, 2001)
    radius = np.array([np.linalg.norm(dyn.tips([angle])[0]) for angle in q])
    assert np.allclose(radius, 1.0 + 0.2 * np.sin(n * q), rtol=0, atol=1e-15)
    maxima = np.flatnonzero((radius[1:-1] > radius[:-2]) & (radius[1:-1] > radius[2:]))
    assert len(maxima) == n
