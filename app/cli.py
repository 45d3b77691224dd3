"""The installed `undertow` command: the library's commands (`planner.cli`); `serve`, which
runs the HTTP service and the viewer under uvicorn; `worker`, a node of solver processes
for a shared job store (`app.worker_node`); `sweep`, which submits a batch to a running
service and prints its summary (`app.sweep_client`); and `backup` and `restore` of the
SQLite job store (`app.store.sqlite_backup`)."""

from __future__ import annotations

import argparse
import os
import sys

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


def _store_path(args: argparse.Namespace) -> str:
    """The SQLite job store a backup or restore works on (--db, else UNDERTOW_DB_PATH);
    BackupFailed for a PostgreSQL store, which has its own tools."""
    from app.settings import get_settings
    from app.store.sqlite_backup import BackupFailed

    settings = get_settings()
    if args.db is None and settings.db_url:
        raise BackupFailed("the job store is PostgreSQL (UNDERTOW_DB_URL): back it up and "
                           "restore it with PostgreSQL's tools (pg_dump, pg_restore)")
    return args.db or settings.db_path


def cmd_backup(args: argparse.Namespace) -> int:
    """A checked copy of the SQLite job store at PATH, taken while the service runs."""
    from app.store.sqlite_backup import BackupFailed, backup

    try:
        copy = backup(_store_path(args), args.path)
    except (BackupFailed, OSError) as exc:
        print(f"undertow backup: {exc}", file=sys.stderr)
        return cli.IO_ERROR
    print(f"backed up {copy.jobs} jobs ({copy.size / 1e6:.1f} MB) to {copy.path}")
    return cli.OK


def cmd_restore(args: argparse.Namespace) -> int:
    """The backup at PATH in the place of the SQLite job store (the service stopped)."""
    from app.store.sqlite_backup import BackupFailed, restore

    try:
        copy = restore(args.path, _store_path(args))
    except (BackupFailed, OSError) as exc:
        print(f"undertow restore: {exc}", file=sys.stderr)
        return cli.IO_ERROR
    aside = "".join(f"\n  {name}" for name in copy.aside) or " (there was none)"
    print(f"restored {copy.jobs} jobs ({copy.size / 1e6:.1f} MB) from {args.path} to "
          f"{copy.path}; the store's earlier files were moved aside:{aside}")
    return cli.OK


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


BACKUP_CODES = f"""exit codes:
  {cli.OK}    the copy passed its integrity check and is in place
  {cli.BAD_INPUT}    wrong option
  {cli.IO_ERROR}    nothing was replaced: the store could not be copied (it is damaged, or a
       PostgreSQL one), the copy failed its check, the store is in use (restore),
       or a file could not be read or written; stderr says which"""


def add_backup(commands: cli.Commands) -> None:
    """The `backup` and `restore` commands of the SQLite job store."""
    store = argparse.ArgumentParser(add_help=False)
    store.add_argument("--db", default=None, metavar="STORE",
                       help="the SQLite job store (default UNDERTOW_DB_PATH)")
    backup = commands.add_parser(
        "backup", parents=[store], epilog=BACKUP_CODES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        help="copy the SQLite job store to PATH while the service runs (checked, compact)")
    backup.add_argument("path", metavar="PATH", help="the backup file (replaced once the "
                                                     "new copy passed its check)")
    backup.set_defaults(run=cmd_backup)
    restore = commands.add_parser(
        "restore", parents=[store], epilog=BACKUP_CODES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        help="put the backup at PATH in the place of the SQLite job store (stop the "
             "service first; the store's files are moved aside)")
    restore.add_argument("path", metavar="PATH", help="a file `undertow backup` wrote")
    restore.set_defaults(run=cmd_restore)


def main(argv: list[str] | None = None) -> int:
    """Run `undertow` with `argv` (default: the command line); returns the exit code."""
    return cli.main(argv, add_serve, add_backup)
