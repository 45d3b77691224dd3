"""What a schemathesis run sent and got back, read from its own NDJSON event report
(`--report ndjson`): every test case (one request each) by operation, phase and the class
of its response's status.

A case of the coverage or fuzzing phase belongs to the operation its scenario tests
(unsupported methods on the operation's path included); a stateful case (a step of a
sequence of calls) to the operation its method and path name.
"""

from __future__ import annotations

import collections
import json
from collections.abc import Iterator
from pathlib import Path

PHASES = ("examples", "coverage", "fuzzing", "stateful")
CLASSES = ("2xx", "3xx", "4xx", "5xx", "no response")
"""The columns of a row: a response's status class, or none (a timeout, a broken
connection)."""


def operations(document: dict) -> dict[str, str]:
    """Every operation of an OpenAPI document: "METHOD /path" -> its operationId."""
    return {f"{method.upper()} {path}": op.get("operationId", "")
            for path, item in document["paths"].items() for method, op in item.items()}


def _interactions(ndjson: Path) -> Iterator[tuple[str, str, int | None]]:
    """(operation, phase, status or None) of every request of the run."""
    with open(ndjson) as f:
        for line in f:
            event = json.loads(line).get("ScenarioFinished")
            if event is None:
                continue
            recorder = event["recorder"]
            cases = recorder.get("cases", {})
            for case_id, interaction in recorder.get("interactions", {}).items():
                case = cases[case_id]["value"]
                label = (f"{case['method']} {case['path']}" if event["phase"] == "stateful"
                         else recorder["label"])
                response = interaction.get("response")
                yield label, event["phase"], response["status_code"] if response else None


def status_class(status: int | None) -> str:
    """"2xx" to "5xx", or "no response"."""
    return "no response" if status is None else f"{status // 100}xx"


def rows(ndjson: Path, document: dict) -> list[dict]:
    """One row per operation of `document` (in its order), then any other label the run
    used (a stateful step the document does not name), each with its cases by phase and
    by status class."""
    known = operations(document)
    counts: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    for label, phase, status in _interactions(ndjson):
        counts[label][phase] += 1
        counts[label][status_class(status)] += 1
    out = []
    for label in [*known, *sorted(set(counts) - set(known))]:
        count = counts[label]
        out.append({"operation": label, "operation_id": known.get(label, ""),
                    "cases": sum(count[p] for p in PHASES),
                    **{p: count[p] for p in PHASES}, **{c: count[c] for c in CLASSES}})
    return out


def total(operation_rows: list[dict]) -> dict:
    """The sum of the rows, as a row "total"."""
    keys = ("cases", *PHASES, *CLASSES)
    return {"operation": "total", "operation_id": "",
            **{k: sum(r[k] for r in operation_rows) for k in keys}}
