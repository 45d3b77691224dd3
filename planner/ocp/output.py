"""The base of every model a plan returns: frozen once made."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Out(BaseModel):
    """A part of a returned plan (frozen)."""

    model_config = ConfigDict(frozen=True)
