"""CasADi functions compiled to C and kept on disk, shared by every process and later run.

A library is named by a digest of what decides its code; it is built on first use (gcc,
in a temporary folder) and renamed into place atomically, so processes sharing the cache
folder never load a partial one. $UNDERTOW_CACHE_DIR names the folder (default
~/.cache/undertow). A caller that need not wait has the library built in the background,
by its builder (`_Builder`: one process of its own at the lowest priority, `python -m
planner.compiled`, which builds what the process asks of it one library after the other
and finishes after the process has gone), and goes on with the interpreted functions
meanwhile. A forked child (a plan's companion) asks the builder of the process it was
forked from (`_ParentsBuilder`) rather than starting one of its own. With
$UNDERTOW_BUILDS=off no background build starts (libraries already on disk are still
loaded), and a cache folder that cannot be made leaves every caller interpreted.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import itertools
import json
import os
import queue
import select
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import casadi as ca


class _Build:
    """A background build this process asked for: its status, None until the builder says
    it ended (0: the library is on disk, else it failed)."""

    def __init__(self) -> None:
        self.status: int | None = None
        self._ended = threading.Event()

    def end(self, status: int) -> None:
        self.status = status
        self._ended.set()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for its end, for at most `timeout` seconds; whether it has ended."""
        return self._ended.wait(timeout)


class _Builder:
    """The process's builder: one `python -m planner.compiled` process that builds the
    libraries asked of it one after the other, each asked for by a JSON line on its stdin
    and reported on its stdout when it ends. A process meeting many structures at once
    thus runs one builder, not a process per library; the builder finishes what it was
    asked after the process has gone (its stdin ends then)."""

    def __init__(self) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "planner.compiled"], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        assert self.process.stdin is not None
        self.fd = self.process.stdin.fileno()
        os.set_blocking(self.fd, False)  # an asker never waits for the builder (`_send`)
        self._pending: dict[str, _Build] = {}
        self._lock = threading.Lock()
        threading.Thread(target=self._listen, name="compiled-builder", daemon=True).start()

    def alive(self) -> bool:
        return self.process.poll() is None

    def ask(self, request: dict[str, Any], build: _Build) -> None:
        """Send a build's request (`_send`'s errors where it could not)."""
        with self._lock:
            self._pending[request["library"]] = build
        try:
            _send(self.fd, request)
        except OSError:
            with self._lock:
                self._pending.pop(request["library"], None)
            raise

    def barrier(self) -> _Build:
        """A request the builder answers once it has ended every request sent before it:
        this process's and those its forked children sent down the same pipe, which it
        reads in order."""
        build = _Build()
        self.ask({"library": f"barrier-{next(_BARRIERS)}", "barrier": True}, build)
        return build

    def _listen(self) -> None:
        """End each build the builder reports; when it has gone, those it left as failed."""
        assert self.process.stdout is not None
        for line in self.process.stdout:
            with contextlib.suppress(ValueError, KeyError, TypeError):
                told = json.loads(line)
                with self._lock:
                    build = self._pending.pop(told["library"])
                build.end(int(told["status"]))
        with self._lock:
            left, self._pending = list(self._pending.values()), {}
        for build in left:
            build.end(1)


class _ParentsBuilder:
    """The builder of the process this one was forked from, as a forked child (a plan's
    companion) asks it: each request is one write of a line shorter than PIPE_BUF down the
    same pipe, which the pipe keeps whole beside the parent's own. Its reports go to the
    parent, so the child's builds stay pending here (`library` finds them on disk once
    built). Without it every companion would start a builder of its own, and each would
    outlive its companion while it waited its turn at the folder's lock: one more process
    for every plan."""

    def __init__(self, fd: int) -> None:
        self.fd = os.dup(fd)  # the child's own, whatever becomes of the parent's objects
        self._open = True

    def alive(self) -> bool:
        return self._open

    def ask(self, request: dict[str, Any], build: _Build) -> None:
        """Send a build's request (`_send`'s errors where it could not)."""
        try:
            _send(self.fd, request)
        except BlockingIOError:
            raise
        except OSError:
            self._open = False
            raise


def _send(fd: int, request: dict[str, Any]) -> None:
    """Write a build's request to a builder's stdin (non-blocking) as one line in one write,
    which a pipe keeps whole beside other writers' lines (shorter than PIPE_BUF). Raises
    BlockingIOError where the pipe is full, so that a plan never waits for a builder, and
    OSError where the builder has gone."""
    line = (json.dumps(request) + "\n").encode()
    if len(line) > select.PIPE_BUF:
        raise OSError(f"a build request of {len(line)} bytes, more than one write keeps whole")
    os.write(fd, line)


_BARRIERS = itertools.count()
_CODEGEN = threading.Lock()  # one compilation at a time per process, and guards the names below
_LOADED: dict[Path, dict[str, ca.Function]] = {}  # libraries loaded by this process
_BUILDING: dict[Path, _Build] = {}  # background builds this process asked for
_BUILDER: _Builder | _ParentsBuilder | None = None  # the process's builder, started with its
# first build, or the one of the process it was forked from


def _forked() -> None:
    """In a forked child (a plan's companion): new locks; the builds the parent asked for
    stay asked (its builder builds them; here they stay pending, so a `wait` in the child
    waits out its timeout), and the child asks the parent's builder for what else it needs
    (`_ParentsBuilder`), starting one of its own only where the parent had none running."""
    global _CODEGEN, _BUILDING, _BUILDER
    _CODEGEN, _BUILDING, _BUILDER = threading.Lock(), dict(_BUILDING), _inherited(_BUILDER)


def _inherited(builder: _Builder | _ParentsBuilder | None) -> _ParentsBuilder | None:
    """The parent's builder as a forked child asks it; None where the parent had none
    running (not asked of the process: its exit status is the parent's to collect)."""
    if isinstance(builder, _ParentsBuilder):
        return _ParentsBuilder(builder.fd) if builder.alive() else None
    if builder is None or builder.process.returncode is not None \
            or builder.process.stdin is None:
        return None
    return _ParentsBuilder(builder.process.stdin.fileno())


os.register_at_fork(after_in_child=_forked)


def cache_dir() -> Path:
    """Where compiled libraries are kept: $UNDERTOW_CACHE_DIR, else ~/.cache/undertow."""
    default = Path.home() / ".cache" / "undertow"
    return Path(os.environ.get("UNDERTOW_CACHE_DIR", default))


def background_builds() -> bool:
    """Whether libraries missing from the cache may be built in the background
    ($UNDERTOW_BUILDS: "background", the default, or "off")."""
    return os.environ.get("UNDERTOW_BUILDS", "background") != "off"


def source_digest(*parts: str, sources: Iterable[Path] = ()) -> str:
    """A stable hash of some text and of the CasADi version and source files that decide
    the generated code."""
    digest = hashlib.sha256(ca.CasadiMeta.version().encode())
    for part in parts:
        digest.update(part.encode())
    for source in sources:
        digest.update(source.read_bytes())
    return digest.hexdigest()[:20]


def library(name: str, functions: Sequence[ca.Function], flags: str = "-O1",
            background: bool = False) -> dict[str, ca.Function] | None:
    """`functions` compiled into the library `name` (a digest-bearing file name without
    suffix), loaded as external functions by name.

    background: when the library is not on disk yet, start building it in a process of
    its own and return None at once (the caller uses the interpreted functions until a
    later call finds it); otherwise build it here and wait.
    """
    folder = cache_dir()
    path = folder / f"{name}.so"
    with _CODEGEN:
        if path in _LOADED:
            return _LOADED[path]
        started = _BUILDING.get(path)
        if not background and started is not None:
            started.wait()  # the build this process asked for in the background, not a second
        if not path.exists():
            if background:
                if background_builds() and _writable(folder):
                    _start(folder, name, functions, flags)
                return None
            folder.mkdir(parents=True, exist_ok=True)
            _build(folder, name, functions, flags)
        return _load(path, [f.name() for f in functions])


def loaded(name: str, names: Sequence[str]) -> dict[str, ca.Function] | None:
    """The functions `names` of the library `name` when it is on disk (loaded once per
    process), without building anything; None when it is not there."""
    path = cache_dir() / f"{name}.so"
    with _CODEGEN:
        if path in _LOADED:
            return _LOADED[path]
        return _load(path, names) if path.exists() else None


def _load(path: Path, names: Sequence[str]) -> dict[str, ca.Function]:
    """The functions `names` of the library at `path`, kept for the process; call under
    _CODEGEN."""
    _LOADED[path] = {f: ca.external(f, str(path)) for f in names}
    return _LOADED[path]


def _writable(folder: Path) -> bool:
    """Whether the cache folder exists or can be made, and takes new files."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(folder, os.W_OK)


def _build(folder: Path, name: str, functions: Sequence[ca.Function], flags: str) -> None:
    """Generate C for `functions`, compile it and rename the library into place."""
    with tempfile.TemporaryDirectory(dir=folder) as work:
        generator = ca.CodeGenerator("lib.c", {"with_header": False})
        for function in functions:
            generator.add(function)
        generator.generate(work + os.sep)
        subprocess.run(["gcc", flags, "-fPIC", "-shared", "lib.c", "-o", "lib.so"],
                       cwd=work, check=True, capture_output=True)
        os.replace(Path(work) / "lib.so", folder / f"{name}.so")


def _start(folder: Path, name: str, functions: Sequence[ca.Function], flags: str) -> None:
    """Ask the process's builder (started where it has none, or it has gone) for the
    library, unless this process already has or its build failed (then the functions stay
    interpreted here); call under _CODEGEN. The functions travel as CasADi's serialised
    files."""
    global _BUILDER
    path = folder / f"{name}.so"
    started = _BUILDING.get(path)
    if started is not None and started.status != 0:
        return
    work = Path(tempfile.mkdtemp(prefix=f"{name}.", dir=folder))
    for function in functions:
        function.save(str(work / f"{function.name()}.casadi"))
    request = {"library": str(path), "folder": str(folder), "name": name, "flags": flags,
               "work": str(work), "functions": [f.name() for f in functions]}
    _BUILDING[path] = build = _Build()
    try:
        if _BUILDER is None or not _BUILDER.alive():
            _BUILDER = _Builder()
        _BUILDER.ask(request, build)
    except BlockingIOError:  # the builder has not read its earlier requests: ask again later
        del _BUILDING[path]
        shutil.rmtree(work, ignore_errors=True)
    except OSError:
        shutil.rmtree(work, ignore_errors=True)
        build.end(1)


def building() -> list[str]:
    """Names of the libraries this process has asked its builder for that have not ended."""
    with _CODEGEN:
        return [path.stem for path, build in _BUILDING.items() if build.status is None]


def started() -> list[str]:
    """Names of the libraries this process has asked to build in the background."""
    with _CODEGEN:
        return [path.stem for path in _BUILDING]


def wait(timeout: float = 600.0) -> list[str]:
    """Wait until the background builds this process asked for have ended, and those its
    forked children (plans' companions) asked its builder for before the wait, for at most
    `timeout` seconds; the names of this process's builds not ended then (none when all
    ended)."""
    deadline = time.monotonic() + timeout
    with _CODEGEN:
        asked, builder = list(_BUILDING.values()), _BUILDER
    for build in asked:
        build.wait(max(deadline - time.monotonic(), 0.0))
    if isinstance(builder, _Builder) and builder.alive():
        with contextlib.suppress(OSError):  # a full pipe or a builder gone: nothing to wait for
            builder.barrier().wait(max(deadline - time.monotonic(), 0.0))
    return building()


BUILD_LOCK = ".build.lock"
"""A file of the cache folder whose lock a background build holds while it compiles: the
builds of one folder run one after the other, whichever processes started them, so that a
service meeting many structures at once runs one compiler beside its solves, not dozens."""


def main() -> None:
    """The builder process: for each request on stdin (a JSON line: library, folder, name,
    flags, work, functions: the names of the functions saved in the folder work), build the
    library of the saved functions, remove their folder
    and say so on stdout (library, status: 0 built or found built, 1 failed); a barrier
    request (library, barrier) is said at once, after every request before it. It runs at
    the lowest priority (nice 19), on the time solves leave idle, and each build after the
    folder's other background builds (BUILD_LOCK); a library another process built
    meanwhile is not built again; a line that is not a request is passed over. It ends
    when its stdin does, after the last request."""
    os.nice(19)
    told = True
    for line in iter(_stdin_lines().get, None):
        try:
            request = json.loads(line)
        except ValueError:
            continue
        status = 0 if request.get("barrier") else _build_asked(request)
        if told:
            try:
                print(json.dumps({"library": request["library"], "status": status}), flush=True)
            except OSError:  # the process that asked has gone: build the rest all the same
                told = False


def _stdin_lines() -> queue.Queue[str | None]:
    """The lines of stdin as a thread reads them, None after the last: the pipe is drained
    while a build runs, so that those asking never find it full."""
    lines: queue.Queue[str | None] = queue.Queue()

    def read() -> None:
        for line in sys.stdin:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, name="requests", daemon=True).start()
    return lines


def _build_asked(request: dict[str, Any]) -> int:
    """Build one requested library: 0 when it is on disk then, 1 when the build failed."""
    folder = Path(request["folder"])
    try:
        with open(folder / BUILD_LOCK, "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (folder / f"{request['name']}.so").exists():
                _build(folder, request["name"],
                       [ca.Function.load(str(Path(request["work"]) / f"{f}.casadi"))
                        for f in request["functions"]], request["flags"])
        return 0
    except (OSError, RuntimeError, subprocess.SubprocessError):
        return 1
    finally:
        shutil.rmtree(request["work"], ignore_errors=True)


if __name__ == "__main__":
    main()
