"""Decision variables of an NLP, laid out as named matrix blocks with bounds and guesses."""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np


@dataclass
class Block:
    """A rows x cols matrix of variables stored column-major at [start, start + size)."""

    name: str
    rows: int
    cols: int
    start: int
    symbol: ca.MX

    @property
    def size(self) -> int:
        return self.rows * self.cols


@dataclass
class Layout:
    """Builds the variable vector block by block; numbers (bounds, guesses) are set later."""

    blocks: dict[str, Block] = field(default_factory=dict)
    size: int = 0

    def add(self, name: str, rows: int, cols: int = 1) -> ca.MX:
        """A new rows x cols block of variables."""
        symbol = ca.MX.sym(name, rows, cols)
        self.blocks[name] = Block(name, rows, cols, self.size, symbol)
        self.size += rows * cols
        return symbol

    def vector(self) -> ca.MX:
        """All variables as one column."""
        return ca.vertcat(*(ca.vec(b.symbol) for b in self.blocks.values()))

    def zeros(self) -> np.ndarray:
        return np.zeros(self.size)

    def view(self, vector: np.ndarray, name: str) -> np.ndarray:
        """The block `name` of a numeric vector, as a rows x cols (writable) view."""
        b = self.blocks[name]
        return vector[b.start:b.start + b.size].reshape(b.cols, b.rows).T

    def __contains__(self, name: str) -> bool:
        return name in self.blocks
