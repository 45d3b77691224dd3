"""The stored results of a suite's long solves, so that its tasks are drawn without solving
again: one JSON file a suite under testbed/suites/data/, its records keyed by the (seed,
index) of the task whose draw needed them, in the order the draw needed them.

A draw asks for the record of its task that matches what it drew (`lookup`); where none
matches it solves, and either way notes what it found (`keep`). `regenerate` draws the
tasks of some seeds and writes what they found; `check` draws every stored seed's tasks
from the stored records alone and reports where they are not what the draws need.
"""

from __future__ import annotations

import contextlib
import json
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Literal, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict

DATA = Path(__file__).with_name("data")
"""Where the suites' stored records lie."""

Key = tuple[int, int]
"""(seed, index) of a task: its random draws come from numpy.random.default_rng(key)."""

Use = Literal["stored", "afresh", "stored-only"]
"""How draws use the stored records: "stored" those that match, solving where none does;
"afresh" none, solving every one; "stored-only" those that match, raising Missing where
none does."""


class Record(BaseModel):
    """A stored record: its fields and no others (read strictly: each of its type)."""

    model_config = ConfigDict(frozen=True, extra="forbid")


R = TypeVar("R", bound=Record)
_NUMBERS = re.compile(r"\[([^\[\]{}\"]*)\]")  # a JSON array of numbers (or nulls)


def close(a, b) -> bool:
    """Whether two configurations [rad] are the same to 1e-9 rad: a stored record's move
    and the move a draw drew (rounded to 1e-6 rad, as every suite rounds its moves)."""
    return len(a) == len(b) and bool(np.allclose(a, b, rtol=0.0, atol=1e-9))


class Missing(LookupError):
    """A draw needs a record that is not stored, and may not solve it."""


class _Entry(BaseModel, Generic[R]):
    model_config = ConfigDict(extra="forbid")

    seed: int
    index: int
    found: list[R]


class _File(BaseModel, Generic[R]):
    model_config = ConfigDict(extra="forbid")

    description: str
    records: list[_Entry[R]]


def read(path: Path, record: type[R]) -> dict[Key, list[R]]:
    """The records stored in `path` by key, each validated strictly as `record` (a JSON
    number of a float field stays the float written)."""
    stored = _File[record].model_validate_json(path.read_text(), strict=True)  # type: ignore[valid-type]
    out: dict[Key, list[R]] = {}
    for entry in stored.records:
        if (entry.seed, entry.index) in out:
            raise ValueError(f"{path.name}: task {(entry.seed, entry.index)} stored twice")
        out[entry.seed, entry.index] = list(entry.found)
    return out


def text(description: str, records: dict[Key, list[R]]) -> str:
    """The JSON text of `records` in key order (floats as repr writes them, so that they
    read back exactly), one field a line, an array of numbers on its field's line."""
    data: dict[str, Any] = {"description": description, "records": [
        {"seed": seed, "index": index,
         "found": [r.model_dump(mode="json") for r in records[seed, index]]}
        for seed, index in sorted(records)]}
    return _NUMBERS.sub(lambda m: "[" + ", ".join(v.strip() for v in m[1].split(",")) + "]",
                        json.dumps(data, indent=1)) + "\n"


@dataclass
class StoredRecords(Generic[R]):
    """The records of one suite's file, how this process's draws use them (`use`) and what
    those draws found (`found`), by key.

    `seeds`: the seeds whose records are stored by default; `keys(seed)`: the keys of a
    seed's tasks that need a record; `draw(key)`: that task, (name, scene)."""

    path: Path
    record: type[R]
    description: str
    seeds: tuple[int, ...]
    keys: Callable[[int], list[Key]]
    draw: Callable[[Key], tuple[str, Any]]
    use: Use = "stored"
    found: dict[Key, list[R]] = field(default_factory=dict)
    _stored: dict[Key, list[R]] | None = field(default=None, init=False, repr=False)

    def stored(self) -> dict[Key, list[R]]:
        """The file's records by key (read once)."""
        if self._stored is None:
            self._stored = read(self.path, self.record)
        return self._stored

    def lookup(self, key: Key | None, matches: Callable[[R], bool]) -> R | None:
        """The first stored record of task `key` that `matches` what its draw drew; None:
        to be solved (no key, none matches, or `use` "afresh")."""
        if key is None or self.use == "afresh":
            return None
        found = next((r for r in self.stored().get(key, []) if matches(r)), None)
        if found is None and self.use == "stored-only":
            raise Missing(f"task {key}: no stored record matches its draw")
        return found

    def keep(self, key: Key | None, record: R) -> None:
        """Note that the draw of task `key` found `record` (once)."""
        if key is not None and record not in self.found.setdefault(key, []):
            self.found[key].append(record)

    @contextlib.contextmanager
    def using(self, use: Use) -> Iterator[None]:
        """Draws within use the stored records as `use` says."""
        saved, self.use = self.use, use
        try:
            yield
        finally:
            self.use = saved

    def regenerate(self, seeds: tuple[int, ...], afresh: bool = False,
                   say: Callable[[str], None] = print) -> None:
        """Draw the tasks of `seeds` that need records, solving those not stored (`afresh`:
        every one), and write what they found beside the stored records of other seeds."""
        drawn: dict[Key, list[R]] = {}
        with self.using("afresh" if afresh else "stored"):
            for key in (key for seed in seeds for key in self.keys(seed)):
                self.found.pop(key, None)
                name, _ = self.draw(key)
                drawn[key] = self.found.get(key, [])
                say(f"{key[0]} {name}: {len(drawn[key])} record(s)")
        records = {k: v for k, v in self.stored().items() if k[0] not in seeds}
        records.update((k, v) for k, v in drawn.items() if v)
        self.path.write_text(text(self.description, records))
        self._stored = None

    def check(self) -> list[str]:
        """What is wrong with the stored records ([] when nothing): the file reads back as
        written; every task of the default and stored seeds that needs records, drawn from
        them alone, finds exactly its stored records, in order; no other task has any."""
        try:
            stored = self.stored()
        except (OSError, ValueError) as error:  # ValueError: pydantic's ValidationError too
            return [f"{self.path.name} does not read: {error}"]
        problems = [] if text(self.description, stored) == self.path.read_text() else [
            f"{self.path.name} is not as regenerate writes it (edited by hand?)"]
        expected = [key for seed in sorted({*self.seeds, *(k[0] for k in stored)})
                    for key in self.keys(seed)]
        saved, self.found = self.found, {}  # what the draws below find, apart
        try:
            for key in expected:
                problems += self._check_draw(key, stored.get(key, []))
        finally:
            self.found = saved
        return problems + [f"task {k}: stored, but its draw needs no record"
                           for k in sorted(set(stored) - set(expected))]

    def _check_draw(self, key: Key, stored: list[R]) -> list[str]:
        """What is wrong with the draw of task `key` from the stored records alone."""
        try:
            with self.using("stored-only"):
                name, _ = self.draw(key)
        except Missing as missing:
            return [str(missing)]
        found = self.found.get(key, [])
        if found != stored:
            return [f"{name} of seed {key[0]}: its draw found {len(found)} of its "
                    f"{len(stored)} stored records"]
        return []
