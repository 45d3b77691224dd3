"""`undertow sweep`: submit a batch to a running service (POST /v1/batches), follow its
progress (GET /v1/batches/{id}) and print its summary table; standard library HTTP only.

Exit codes: 0 when every member succeeded, 1 when some did not (or the batch did not end
within --timeout), 2 when the service refused the request (each offending field is
printed), 3 when the service cannot be reached.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import urllib.error
import urllib.request
from typing import Any, TextIO

from planner import cli
from planner.errors import InputError

POLL = 1.0  # [s] between two looks at the batch
REQUEST_TIMEOUT = 30.0  # [s] for one HTTP request


def _call(method: str, url: str, key: str | None, body: Any = None) -> tuple[int, Any]:
    """(status, JSON body) of one request; OutputError when the service is unreachable."""
    data = None if body is None else json.dumps(body).encode()
    headers = {"content-type": "application/json", **({"x-api-key": key} if key else {})}
    request = urllib.request.Request(url, data=data, method=method, headers=headers)
    try:
        with urllib.request.urlopen(request, timeout=REQUEST_TIMEOUT) as response:
            return response.status, json.load(response)
    except urllib.error.HTTPError as exc:
        try:
            return exc.code, json.load(exc)
        except ValueError:
            return exc.code, {"detail": exc.reason}
    except (urllib.error.URLError, OSError) as exc:
        raise cli.OutputError(f"cannot reach {url}: {getattr(exc, 'reason', exc)}") from exc


def _refused(status: int, problem: dict[str, Any]) -> InputError:
    lines = [f"the service refused the batch ({status}): {problem.get('detail', '')}"]
    for error in problem.get("errors") or []:
        lines.append(f"  {'.'.join(map(str, error['loc']))}: {error['msg']}")
    return InputError("\n".join(lines))


def table(batch: dict[str, Any]) -> str:
    """The summary table: one line per member."""
    rows = [f"{'member':>6}  {'status':<9}  {'verified':<8}  {'objective':>12}  {'time [s]':>8}"
            "  parameters"]
    for m in batch["members"]:
        objective = "" if m["objective"] is None else f"{m['objective']:.6g}"
        took = "" if m["time"] is None else f"{m['time']:.2f}"
        verified = "" if m["verified"] is None else ("yes" if m["verified"] else "no")
        params = ", ".join(f"{k}={v:g}" for k, v in m["parameters"].items())
        rows.append(f"{m['index']:>6}  {m['status']:<9}  {verified:<8}  {objective:>12}  "
                    f"{took:>8}  {params}")
    counts = ", ".join(f"{n} {s}" for s, n in batch["counts"].items() if n)
    rows.append(f"batch {batch['id']}: {batch['size']} members ({counts}); "
                f"{batch['verified']} verified")
    return "\n".join(rows)


class Follow:
    """The batch's progress on a stream: on a terminal one line rewritten in place at every
    look (with the time waited); on a file or a pipe a line only when the counts change, so
    a log holds one line per finished member rather than one per second."""

    def __init__(self, stream: TextIO):
        self.stream, self.tty = stream, stream.isatty()
        self.last: str | None = None

    def show(self, batch: dict[str, Any], waited: float) -> None:
        line = f"  {batch['finished']}/{batch['size']} finished, {batch['verified']} verified"
        if self.tty:
            self.stream.write(f"\r{line}  {waited:5.0f} s")
        elif line != self.last:
            self.stream.write(line + "\n")
        self.stream.flush()
        self.last = line

    def close(self) -> None:
        """End the line rewritten in place."""
        if self.tty and self.last is not None:
            self.stream.write("\n")
            self.stream.flush()


def run(args: argparse.Namespace) -> int:
    """Submit, follow and summarise one batch (see the module for the exit codes)."""
    request = cli.read_json(args.request)
    base = args.url.rstrip("/")
    status, batch = _call("POST", f"{base}/v1/batches", args.api_key, request)
    if status != 202:
        raise _refused(status, batch)
    print(f"batch {batch['id']}: {batch['size']} members queued", file=sys.stderr, flush=True)
    if args.no_wait:
        print(batch["id"])
        return cli.OK
    started = time.monotonic()
    deadline, follow = started + args.timeout, Follow(sys.stderr)
    while batch["finished"] < batch["size"] and time.monotonic() < deadline:
        time.sleep(POLL)
        status, batch = _call("GET", f"{base}/v1/batches/{batch['id']}", args.api_key)
        if status != 200:
            follow.close()
            raise cli.OutputError(f"the service answered {status}: {batch.get('detail', '')}")
        follow.show(batch, time.monotonic() - started)
    follow.close()
    print(table(batch), file=sys.stderr)
    if args.output:
        cli.write(args.output, json.dumps(batch) + "\n")
    done = batch["finished"] == batch["size"]
    return cli.OK if done and batch["counts"]["succeeded"] == batch["size"] else cli.FAILED
