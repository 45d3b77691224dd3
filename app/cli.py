"""The installed `undertow` command: the library's commands (`planner.cli`); `serve`, which
runs the HTTP service and the viewer under uvicorn; `worker`, a node of solver processes
for a shared job store (`app.worker_node`); and `sweep`, which submits a batch to a
running service and prints its summary (`app.sweep_client`)."""

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


def cmd_worker(args: argparse.Namespace) -> int:
    """A worker node on the configured job store (UNDERTOW_DB_URL for several machines)."""
    from app import worker_node
    from app.settings import get_settings

    settings = get_settings()
    return worker_node.run(settings, args.processes or settings.workers or 1,
                           metrics=(args.metrics_host, args.metrics_port)
                           if args.metrics_port else None)


def cmd_sweep(args: argparse.Namespace) -> int:
    """POST the batch request to the service, follow it, write its summary."""
    from app import sweep_client

    return sweep_client.run(args)


def positive(text: str) -> int:
    """An integer of at least 1, for argparse."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1 (got {value})")
    return value


def count(text: str) -> int:
    """An integer of at least 0, for argparse."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be at least 0 (got {value})")
    return value


def add_serve(commands: cli.Commands) -> None:
    """The `serve`, `worker` and `sweep` commands."""
    serve = commands.add_parser("serve", help="run the HTTP service and the viewer at /")
    serve.add_argument("--host", default="127.0.0.1", help="interface (default 127.0.0.1)")
    serve.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    serve.add_argument("--workers", type=count, default=None,
                       help="solver worker processes (UNDERTOW_WORKERS; default 2; 0: API "
                            "only, for `undertow worker` nodes to run the plans)")
    serve.set_defaults(run=cmd_serve)

    worker = commands.add_parser(
        "worker", help="run solver processes only, for every server sharing the job store "
                       "(UNDERTOW_DB_URL)")
    worker.add_argument("--processes", type=positive, default=None,
                        help="solver processes (default UNDERTOW_WORKERS, 2)")
    worker.add_argument("--metrics-port", type=positive, default=None,
                        help="serve Prometheus metrics at http://HOST:PORT/metrics "
                             "(default: none)")
    worker.add_argument("--metrics-host", default="127.0.0.1",
                        help="interface of the metrics (default 127.0.0.1)")
    worker.set_defaults(run=cmd_worker)

    sweep = commands.add_parser("sweep", help="submit a batch sweep to a running service and "
                                              "print its summary table",
                                epilog=cli.EXIT_CODES,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sweep.add_argument("request", metavar="BATCH.json",
                       help='POST /v1/batches body: base and overrides or grid ("-": stdin)')
    sweep.add_argument("--url", default="http://127.0.0.1:8000",
                       help="the service (default http://127.0.0.1:8000)")
    sweep.add_argument("--api-key", default=os.environ.get("UNDERTOW_API_KEY"),
                       help="X-API-Key (default $UNDERTOW_API_KEY)")
    sweep.add_argument("-o", "--output", metavar="SUMMARY.json",
                       help='where to write the final summary ("-": stdout)')
    sweep.add_argument("--timeout", type=float, default=3600.0,
                       help="seconds to follow the batch before giving up (default 3600)")
    sweep.add_argument("--no-wait", action="store_true",
                       help="print the batch id and return once it is accepted")
    sweep.set_defaults(run=cmd_sweep)


def main(argv: list[str] | None = None) -> int:
    """Run `undertow` with `argv` (default: the command line); returns the exit code."""
    return cli.main(argv, add_serve)
