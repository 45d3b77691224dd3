"""CasADi functions compiled to C and kept on disk, shared by every process and later run.

A library is named by a digest of what decides its code; it is built on first use (gcc,
in a temporary folder) and renamed into place atomically, so processes sharing the cache
folder never load a partial one. $UNDERTOW_CACHE_DIR names the folder (default
~/.cache/undertow). A caller that need not wait has the library built in the background,
by a process of its own at the lowest priority (`python -m planner.compiled`), and goes on
with the interpreted functions meanwhile. With $UNDERTOW_BUILDS=off no background build
starts (libraries already on disk are still loaded), and a cache folder that cannot be
made leaves every caller interpreted.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path

import casadi as ca

_CODEGEN = threading.Lock()  # one compilation at a time per process, and guards the dicts below
_LOADED: dict[Path, dict[str, ca.Function]] = {}  # libraries loaded by this process
_BUILDING: dict[Path, subprocess.Popen] = {}  # background builds started by this process


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
        if not background and started is not None and started.poll() is None:
            started.wait()  # the build this process started in the background, not a second
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
    """Build the library in a child process, unless this process already is or its build
    failed (then the functions stay interpreted here); call under _CODEGEN. The functions
    travel as CasADi's serialised files."""
    path = folder / f"{name}.so"
    started = _BUILDING.get(path)
    if started is not None and started.poll() != 0:
        return
    work = Path(tempfile.mkdtemp(prefix=f"{name}.", dir=folder))
    files = []
    for function in functions:
        files.append(str(work / f"{function.name()}.casadi"))
        function.save(files[-1])
    _BUILDING[path] = subprocess.Popen(
        [sys.executable, "-m", "planner.compiled", str(folder), name, flags, str(work), *files],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def building() -> list[str]:
    """Names of the libraries this process is building in the background."""
    with _CODEGEN:
        return [path.stem for path, proc in _BUILDING.items() if proc.poll() is None]


def started() -> list[str]:
    """Names of the libraries this process has started building in the background."""
    with _CODEGEN:
        return [path.stem for path in _BUILDING]


def wait(timeout: float = 600.0) -> list[str]:
    """Wait until the background builds this process started have ended, for at most
    `timeout` seconds; the names of those still building then (none when all ended)."""
    deadline = time.monotonic() + timeout
    with _CODEGEN:
        running = list(_BUILDING.values())
    for proc in running:
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(max(deadline - time.monotonic(), 0.0))
    return building()


BUILD_LOCK = ".build.lock"
"""A file of the cache folder whose lock a background build holds while it compiles: the
builds of one folder run one after the other, whichever processes started them, so that a
service meeting many structures at once runs one compiler beside its solves, not dozens."""


def main(argv: list[str]) -> None:
    """Child process: folder name flags work file...: build the library of the saved
    functions, then remove their folder. It runs at the lowest priority (nice 19), on the
    time solves leave idle, and after the folder's other background builds (BUILD_LOCK);
    a library another process built meanwhile is not built again."""
    os.nice(19)
    folder, name, flags, work, *files = argv
    try:
        with open(Path(folder) / BUILD_LOCK, "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (Path(folder) / f"{name}.so").exists():
                _build(Path(folder), name, [ca.Function.load(f) for f in files], flags)
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main(sys.argv[1:])
