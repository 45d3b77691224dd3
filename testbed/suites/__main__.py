"""The suites' stored records (testbed/suites/data/): check them, or solve and write them again.

    python -m testbed.suites check
    python -m testbed.suites regenerate [--suite hard|impossible] [--seed S ...] [--afresh]

`check` (seconds, no solve) reads every stored file strictly and draws, from the stored
records alone, every task of the suite's seeds and of the stored ones that needs a record:
each must find exactly its stored records; it exits 1 on any problem. `regenerate` draws
the tasks of the seeds given (default: the suite's SEED and HELD_OUT) with the stored
records that still match their draws, solves the others (`--afresh`: every one; minutes
to hours) and writes them, beside the stored records of other seeds.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from testbed.suites import hard, impossible
from testbed.suites.records import StoredRecords

STORED: dict[str, StoredRecords[Any]] = {"hard": hard.WITNESSES,
                                         "impossible": impossible.REFERENCES}


def check() -> int:
    """Check every stored file, print what it holds and its problems; 1 if any."""
    failed = False
    for name, store in STORED.items():
        problems = store.check()
        failed |= bool(problems)
        try:
            stored = store.stored()
        except (OSError, ValueError):
            stored = {}
        seeds = ", ".join(str(s) for s in sorted({seed for seed, _ in stored}))
        verdict = f"{len(problems)} problem(s)" if problems else "each the draw of its task"
        print(f"{name}: {store.path.name}: {len(stored)} tasks of seeds {seeds}, "
              f"{sum(len(v) for v in stored.values())} records: {verdict}")
        for problem in problems:
            print(f"  {problem}")
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m testbed.suites", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("check", help="check the stored records (fast, no solve)")
    again = commands.add_parser("regenerate", help="solve and write the stored records")
    again.add_argument("--suite", choices=sorted(STORED), action="append",
                       help="the suite (repeatable; default: every one)")
    again.add_argument("--seed", type=int, action="append", default=[],
                       help="a seed to draw (repeatable; default: the suite's SEED and HELD_OUT)")
    again.add_argument("--afresh", action="store_true",
                       help="solve every record again, not only those no longer drawn")
    args = parser.parse_args(argv)
    if args.command == "check":
        return check()
    for name in args.suite or sorted(STORED):
        store = STORED[name]
        store.regenerate(tuple(args.seed) or store.seeds, args.afresh)
        print(f"{name}: wrote {store.path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
