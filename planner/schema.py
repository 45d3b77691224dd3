"""What the request models of the library share: their configuration and the joint state.

Requests are JSON documents: unknown fields are refused, values are frozen, and numbers
must be finite JSON numbers. `strict` refuses what pydantic's lax mode would convert: a
string ("0.1") or a boolean (true) where a number belongs, a fractional number (3.0 is
fine, 3.5 is not) where an integer belongs. An integer is still a valid real number, and
nested objects are read from JSON objects as usual.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

REQUEST = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, strict=True)


class JointState(BaseModel):
    """Joint angles q [rad] and rates dq [rad/s], every entry given; which joints, and how
    many, the field holding it says."""

    model_config = REQUEST

    q: list[float]
    dq: list[float]
