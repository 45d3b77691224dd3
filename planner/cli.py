"""The library's commands of `undertow`: list examples, plan, design waves, and run the
classical inverse dynamics from JSON files (the same request bodies as the service).
`app.cli` adds `serve` and is the installed command; the library knows nothing of HTTP.

Exit codes are part of the interface; see EXIT_CODES and `undertow --help`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TextIO, TypeVar

from pydantic import BaseModel, ValidationError

from planner.errors import InputError, located

OK, FAILED, BAD_INPUT, IO_ERROR, INTERRUPTED = 0, 1, 2, 3, 130
EXIT_CODES = f"""exit codes:
  {OK}    success
  {FAILED}    the computation ran but did not succeed: solver failure or infeasible plan,
       a plan whose torque fails the re-simulation check, infeasible wave design,
       singular stop of the inverse dynamics; the result is still written
  {BAD_INPUT}    bad input: unreadable JSON, a field that fails validation (each offending
       field is named on stderr), unknown example, wrong option
  {IO_ERROR}    I/O error: an input file cannot be read or an output file cannot be written
  {INTERRUPTED}  interrupted (Ctrl-C); a plan stopped by Ctrl-C is still written"""

PROGRESS_PERIOD = 1.0
"""[s] between two progress lines when stderr is not a terminal."""

M = TypeVar("M", bound=BaseModel)


class OutputError(Exception):
    """A file could not be read or written: exit code 3."""


# --------------------------------------------------------------------------- files


def read_json(path: str) -> Any:
    """The JSON document in a file ("-": standard input)."""
    try:
        text = sys.stdin.read() if path == "-" else Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise OutputError(f"cannot read {path}: {getattr(exc, 'strerror', None) or exc}") from exc
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: "
                         f"{exc.msg})") from exc


def write(path: str, data: bytes | str) -> None:
    """Write a whole file atomically (a temporary file renamed into place; "-": stdout)."""
    if path == "-":
        if isinstance(data, bytes):
            sys.stdout.buffer.write(data)
        else:
            sys.stdout.write(data)
        sys.stdout.flush()
        return
    target = Path(path)
    temporary = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        temporary.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8"))
        os.replace(temporary, target)
    except OSError as exc:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from exc


def field_messages(error: ValidationError) -> list[str]:
    """One "field.path: what is wrong" line per offending field."""
    lines = []
    for item in error.errors():
        path, msg = located(item["msg"])
        loc = [str(p) for p in [*item["loc"], *path]]
        where = "".join(f"[{p}]" if p.isdigit() else f".{p}" for p in loc).lstrip(".")
        lines.append(f"{where}: {msg}" if where else msg)
    return lines


def load(model: type[M], path: str) -> M:
    """A request model read from a JSON file; InputError names every offending field."""
    data = read_json(path)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        lines = field_messages(exc)
        raise InputError("\n".join([f"{path}: {len(lines)} invalid field(s)"]
                                   + [f"  {line}" for line in lines])) from exc


def dump(model: BaseModel) -> str:
    """Compact JSON of a result, one line."""
    return model.model_dump_json() + "\n"


# --------------------------------------------------------------------------- progress


class ProgressBar:
    """Ipopt's iterations on a stream: a line redrawn in place on a terminal, otherwise a
    line every PROGRESS_PERIOD seconds. Returns False (stop the solve) once `stop` is set."""

    def __init__(self, stream: TextIO, visible: bool = True):
        self.stream, self.visible = stream, visible
        self.tty = stream.isatty()
        self.last_draw, self.stop, self.drawn = -float("inf"), False, False
        self.latest = None
        self.lock = threading.Lock()  # the heartbeat of `waiting` writes from its own thread

    def _write(self, text: str) -> None:
        with self.lock:
            self.stream.write(text + ("\r" if self.tty else "\n"))
            self.stream.flush()

    @contextlib.contextmanager
    def waiting(self, what: str) -> Iterator[None]:
        """Until the first iteration: "<what>  <elapsed> s" at the bar's pace, so that a long
        NLP build or initial guess shows that work is going on."""
        done, started = threading.Event(), time.monotonic()

        def beat() -> None:
            period = max(0.1 if self.tty else PROGRESS_PERIOD, 0.05)
            while not done.wait(period) and self.latest is None:
                self._write(f"{what}  {time.monotonic() - started:6.1f} s")

        thread = threading.Thread(target=beat, daemon=True)
        if self.visible:
            thread.start()
        try:
            yield
        finally:
            done.set()
            if thread.is_alive():
                thread.join()

    def line(self, progress) -> str:
        inf_du = "n/a" if progress.inf_du is None else f"{progress.inf_du:.2e}"
        return (f"[mesh pass {progress.mesh_pass}] iteration {progress.iteration:>5}  "
                f"objective {progress.objective:.6e}  inf_pr {progress.inf_pr:.2e}  "
                f"inf_du {inf_du}  {progress.elapsed:6.1f} s")

    def __call__(self, progress) -> bool:
        self.latest = progress
        now = time.monotonic()
        period = 0.1 if self.tty else PROGRESS_PERIOD
        if self.visible and now - self.last_draw >= period:
            self.last_draw, self.drawn = now, True
            self._write(self.line(progress))
        return not self.stop

    def close(self) -> None:
        """On a terminal: redraw the last iteration and end the line."""
        if self.tty and self.drawn:
            with self.lock:
                self.stream.write(self.line(self.latest) + "\n")
                self.stream.flush()


@contextlib.contextmanager
def first_interrupt_stops(bar: ProgressBar) -> Iterator[None]:
    """The first Ctrl-C asks the solver to stop at its next iteration; a second one
    interrupts at once."""
    def handler(signum, frame):
        bar.stop = True
        signal.signal(signal.SIGINT, signal.default_int_handler)
        print("\nstopping at the next iteration (Ctrl-C again to abort)", file=sys.stderr)
    try:
        previous = signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main thread: leave Ctrl-C alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def say(args: argparse.Namespace, message: str) -> None:
    if not getattr(args, "quiet", False):
        print(message, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- commands


def check_plot_name(path: str | None) -> None:
    """InputError unless `path` is None or names a figure format."""
    if path is not None:
        from planner.plots import format_of
        format_of(path)


def cmd_plan(args: argparse.Namespace) -> int:
    from planner.ocp import plan
    from planner.scene import Scene

    check_plot_name(args.plot)
    scene = load(Scene, args.scene)
    tr = scene.transcription
    say(args, f"planning {args.scene}: {scene.robot.n} links, {tr.method}, "
              f"{tr.intervals} intervals (building the NLP the first time takes a while)")
    bar = ProgressBar(sys.stderr, visible=not args.quiet)
    with first_interrupt_stops(bar), bar.waiting("building the NLP and the initial guess"):
        result = plan(scene, progress=bar)
    bar.close()
    write(args.output, dump(result))
    if args.plot and result.t:  # an infeasible task refused before a solve has no plan
        from planner.plots import format_of, plan_plot
        write(args.plot, plan_plot(result, scene.robot, format_of(args.plot), scene.task))
        say(args, f"wrote the plan's figure to {args.plot}")
    s, v = result.solver, result.verification
    local = "n/a" if v.local_error is None else f"{v.local_error:.2g} rad"
    resim = "n/a" if v.resimulation_error is None else f"{v.resimulation_error:.2g} rad"
    say(args, f"{s.status}: {s.message}; {s.iterations} iterations in "
              f"{len(result.mesh_passes)} solve(s) ({s.strategy}), solve {s.solve_time:.2f} s, "
              f"build {s.build_time:.2f} s; {max(len(result.t) - 1, 0)} intervals, error {local} "
              f"per interval, open-loop replay {resim}; "
              f"{len(v.waveless_singular_crossings)} waveless singular crossing(s)")
    if bar.stop:
        return INTERRUPTED
    say(args, result.message or result.status or "")
    return OK if result.status == "verified" else FAILED


def cmd_design_wave(args: argparse.Namespace) -> int:
    from planner.waves import WaveDesignRequest, design

    request = load(WaveDesignRequest, args.request)
    say(args, f"designing waves for {args.request} ...")
    result = design(request)
    write(args.output, dump(result))
    waves = ", ".join(f"joint {w.joint}: a={w.amplitude:.4g} n={w.frequency} "
                      f"eps={w.phase:.4g}" for w in result.waves)
    c = result.certificate
    say(args, f"{result.status}: sigma_min proven >= {c.bound:.4g} (sampled minimum "
              f"{c.sampled_min:.4g}, margin {request.margin:g}; {c.boxes:,} boxes in "
              f"{c.seconds:.2g} s); {waves}")
    return OK if result.status == "certified" else FAILED


def cmd_inverse(args: argparse.Namespace) -> int:
    from planner.inverse import InverseDynamicsRequest, solve

    check_plot_name(args.plot)
    request = load(InverseDynamicsRequest, args.request)
    result = solve(request)
    write(args.output, dump(result))
    if args.plot:
        from planner.plots import format_of, inverse_plot
        write(args.plot, inverse_plot(result, request, format_of(args.plot)))
        say(args, f"wrote the figure to {args.plot}")
    say(args, f"{result.status}: {result.message}")
    return OK if result.status == "completed" else FAILED


def cmd_examples(args: argparse.Namespace) -> int:
    from planner.examples import example, examples

    if args.name is None:
        if args.output is not None:
            raise InputError("-o/--output: needs --name (which example to write)")
        items = [e for e in examples() if args.kind is None or e.kind == args.kind]
        width = max((len(e.name) for e in items), default=4)
        lines = [f"{e.name:<{width}}  {e.kind:<16}  {e.title}" for e in items]
        write("-", "\n".join(lines) + ("\n" if lines else ""))
        return OK
    try:
        item = example(args.name)
    except KeyError as exc:
        raise InputError(f"--name: {exc.args[0]}") from exc
    if args.kind is not None and item.kind != args.kind:
        raise InputError(f"--name: {args.name!r} is of kind {item.kind!r}, not {args.kind!r}")
    write(args.output or "-", json.dumps(item.request, indent=1) + "\n")
    if args.output not in (None, "-"):
        command = _COMMANDS.get(item.kind)
        use = (f"undertow {command} {args.output} -o OUT.json" if command
               else f"the service takes it (docs/api.md, the {item.kind} endpoint)")
        say(args, f"wrote the {item.kind} request {item.name!r} to {args.output}; next: {use}")
    return OK


_COMMANDS = {"plan": "plan", "inverse-dynamics": "inverse", "wave-design": "design-wave",
             "coupling": None}
"""Every kind of example (`planner.examples.Kind`) and the command that runs it (None: only
the service does)."""


# --------------------------------------------------------------------------- parser


Commands = argparse._SubParsersAction
"""What `parser`'s extensions add their commands to."""


def parser(*extensions: Callable[[Commands], None]) -> argparse.ArgumentParser:
    """The argument parser of `undertow`: each extension adds commands (before the
    library's own, in the help)."""
    top = argparse.ArgumentParser(
        prog="undertow", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Plan feed-forward torques for underactuated planar arms with wavy\n"
                    "active joints. Inputs are the JSON bodies of the HTTP API\n"
                    "(`undertow examples` lists ready ones); SI units, radians.",
        epilog=EXIT_CODES)
    commands = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for extend in extensions:
        extend(commands)

    ex = commands.add_parser("examples", help="list the built-in examples or write one")
    ex.add_argument("--kind", choices=sorted(_COMMANDS), help="only examples of this kind")
    ex.add_argument("--name", help="write this example's request body")
    ex.add_argument("-o", "--output", help="file for --name (default: stdout)")
    ex.set_defaults(run=cmd_examples)

    raw: dict[str, Any] = {"epilog": EXIT_CODES,
                           "formatter_class": argparse.RawDescriptionHelpFormatter}
    pl = commands.add_parser("plan", help="plan a scene (optimal control, Ipopt)", **raw)
    pl.add_argument("scene", metavar="SCENE.json", help='scene file ("-": stdin)')
    pl.add_argument("-o", "--output", required=True, metavar="PLAN.json",
                    help='where to write the plan ("-": stdout)')
    pl.add_argument("--plot", metavar="PLAN.png|PLAN.svg", help="also draw the plan")
    pl.add_argument("-q", "--quiet", action="store_true", help="no progress lines or summary")
    pl.set_defaults(run=cmd_plan)

    dw = commands.add_parser("design-wave", help="design waves that keep sigma_min >= margin",
                             **raw)
    dw.add_argument("request", metavar="REQUEST.json", help='wave-design request ("-": stdin)')
    dw.add_argument("-o", "--output", required=True, metavar="OUT.json")
    dw.add_argument("-q", "--quiet", action="store_true", help="no summary on stderr")
    dw.set_defaults(run=cmd_design_wave)

    inv = commands.add_parser("inverse", help="classical inverse dynamics of a passive motion",
                              **raw)
    inv.add_argument("request", metavar="REQUEST.json",
                     help='inverse-dynamics request ("-": stdin)')
    inv.add_argument("-o", "--output", required=True, metavar="OUT.json")
    inv.add_argument("--plot", metavar="OUT.png|OUT.svg", help="also draw the result")
    inv.add_argument("-q", "--quiet", action="store_true", help="no summary on stderr")
    inv.set_defaults(run=cmd_inverse)
    return top


def main(argv: list[str] | None = None,
         *extensions: Callable[[Commands], None]) -> int:
    """Run `undertow` with `argv` (default: the command line) and the commands of
    `extensions` (see `parser`); returns the exit code."""
    args = parser(*extensions).parse_args(argv)
    run: Callable[[argparse.Namespace], int] = args.run
    try:
        return run(args)
    except InputError as exc:  # unreadable input, or what the library refuses of it
        print(f"undertow {args.command}: {exc}", file=sys.stderr)
        return BAD_INPUT
    except OutputError as exc:
        print(f"undertow {args.command}: {exc}", file=sys.stderr)
        return IO_ERROR
    except KeyboardInterrupt:
        print(f"undertow {args.command}: interrupted", file=sys.stderr)
        return INTERRUPTED
