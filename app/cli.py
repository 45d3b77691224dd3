"""The installed `undertow` command: the library's commands (`planner.cli`) and `serve`,
which runs the HTTP service and the viewer under uvicorn."""

from __future__ import annotations

import argparse
import os

from planner import cli


def cmd_serve(args: argparse.Namespace) -> int:
    """uvicorn serving `app.main:app` with the service's protocol (`app.server`)."""
    import uvicorn

    from app.server import PROTOCOL

    if args.workers is not None:
        os.environ["UNDERTOW_WORKERS"] = str(args.workers)
    uvicorn.run("app.main:app", host=args.host, port=args.port, http=PROTOCOL)
    return cli.OK


def positive(text: str) -> int:
    """An integer of at least 1, for argparse."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1 (got {value})")
    return value


def add_serve(commands: cli.Commands) -> None:
    """The `serve` command."""
    serve = commands.add_parser("serve", help="run the HTTP service and the viewer at /")
    serve.add_argument("--host", default="127.0.0.1", help="interface (default 127.0.0.1)")
    serve.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    serve.add_argument("--workers", type=positive, default=None,
                       help="solver worker processes (UNDERTOW_WORKERS; default 2)")
    serve.set_defaults(run=cmd_serve)


def main(argv: list[str] | None = None) -> int:
    """Run `undertow` with `argv` (default: the command line); returns the exit code."""
    return cli.main(argv, add_serve)
