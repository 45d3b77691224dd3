"""What the request models of the library share: their configuration and the joint state.

Requests are JSON documents: unknown fields are refused, values are frozen, and numbers
must be finite JSON numbers. Joint angles and rates are bounded further, by `STATE_MAX`
(`Angle`, `Rate`): a finite double as large as 1e308 passes JSON but not the dynamics
(sin and cos lose every digit, products overflow), so it is refused at its field.
`strict` refuses what pydantic's lax mode would convert: a string ("0.1") or a boolean
(true) where a number belongs, a fractional number (3.0 is fine, 3.5 is not) where an
integer belongs. An integer is still a valid real number, and nested objects are read
from JSON objects as usual.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

REQUEST = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)

STATE_MAX = 1e6
"""The largest magnitude of a requested joint angle [rad] or rate [rad/s]: far beyond any
motion (1e6 rad is 159,155 turns), and small enough that sin and cos keep ten significant
digits and every product in the dynamics stays finite."""

DURATION_MIN, DURATION_MAX = 1e-2, 1e4
"""[s] The durations a request may state: a motion shorter than 10 ms asks torques beyond
any arm's (they grow as 1 / T^2) and holds a computation as long as a sensible one, and one
longer than 10^4 s is no single motion."""
Duration = Annotated[float, Field(ge=DURATION_MIN, le=DURATION_MAX)]
"""A motion's duration T [s] of a request."""

Angle = Annotated[float, Field(ge=-STATE_MAX, le=STATE_MAX)]
"""A joint angle [rad] of a request, |q| <= STATE_MAX."""
Rate = Annotated[float, Field(ge=-STATE_MAX, le=STATE_MAX)]
"""A joint rate [rad/s] of a request, |dq| <= STATE_MAX."""


class JointState(BaseModel):
    """Joint angles q [rad] and rates dq [rad/s], every entry given; which joints, and how
    many, the field holding it says."""

    model_config = REQUEST

    q: list[Angle]
    dq: list[Rate]
