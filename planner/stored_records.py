"""Python modules that hold the results of long solves, keyed by (seed, index), so that a
generated suite can be drawn without solving again (`planner.hard_suite_witnesses`,
`planner.impossible_suite_references`)."""

from __future__ import annotations

import pprint
import textwrap
from typing import Any

Records = dict[tuple[int, int], list[dict[str, Any]]]


def module_text(docstring: str, name: str, records: Records) -> str:
    """A module's text: `docstring`, then `name` holding `records` in key order, each
    record a dict as pprint writes it."""
    lines = [f'"""{docstring}"""\n\nfrom typing import Any\n\n'
             f"{name}: dict[tuple[int, int], list[dict[str, Any]]] = {{"]
    for key in sorted(records):
        lines.append(f"    {key!r}: [")
        lines += [textwrap.indent(pprint.pformat(r, width=91, sort_dicts=False), " " * 8) + ","
                  for r in records[key]]
        lines.append("    ],")
    return "\n".join([*lines, "}", ""])
