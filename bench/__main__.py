"""`python -m bench NAME [options]` runs the benchmark NAME; `python -m bench list` lists them."""

from __future__ import annotations

import importlib
import sys

BENCHES = {
    "build": ("bench.build", "building an NLP against the number of links, now and at an "
                             "earlier commit"),
    "examples": ("bench.examples", "the built-in plan examples, now and at an earlier commit"),
    "refinement": ("bench.refinement", "mesh refinement on the two-link example at other "
                                       "numbers of intervals; what each retry recovers"),
    "suite": ("bench.suite", "the task suite: verified plans and time to a verified plan, "
                             "against refinement off, retries off and a plain Opti script"),
}
"""Every benchmark: its module (with main(argv)) and what it measures."""


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("list", "-h", "--help"):
        width = max(map(len, BENCHES))
        for name, (_, what) in BENCHES.items():
            print(f"{name:<{width}}  {what}")
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in BENCHES:
        print(f"no benchmark called {name!r}; `python -m bench list` lists them", file=sys.stderr)
        return 2
    return importlib.import_module(BENCHES[name][0]).main(rest) or 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
