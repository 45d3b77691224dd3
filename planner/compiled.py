"""CasADi functions compiled to C and kept on disk, shared by every process and later run.

A library is named by a digest of what decides its code; it is built on first use (gcc,
in a temporary folder) and renamed into place atomically, so processes sharing the cache
folder never load a partial one. $UNDERTOW_CACHE_DIR names the folder (default
~/.cache/undertow).
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import tempfile
import threading
from collections.abc import Iterable, Sequence
from pathlib import Path

import casadi as ca

_CODEGEN = threading.Lock()  # one compilation at a time per process


def cache_dir() -> Path:
    """Where compiled libraries are kept: $UNDERTOW_CACHE_DIR, else ~/.cache/undertow."""
    default = Path.home() / ".cache" / "undertow"
    return Path(os.environ.get("UNDERTOW_CACHE_DIR", default))


def source_digest(*parts: str, sources: Iterable[Path] = ()) -> str:
    """A stable hash of some text and of the CasADi version and source files that decide
    the generated code."""
    digest = hashlib.sha256(ca.__version__.encode())
    for part in parts:
        digest.update(part.encode())
    for source in sources:
        digest.update(source.read_bytes())
    return digest.hexdigest()[:20]


def library(name: str, functions: Sequence[ca.Function],
            flags: str = "-O1") -> dict[str, ca.Function]:
    """`functions` compiled into the library `name` (a digest-bearing file name without
    suffix), loaded as external functions by name."""
    folder = cache_dir()
    path = folder / f"{name}.so"
    if not path.exists():
        folder.mkdir(parents=True, exist_ok=True)
        with _CODEGEN, tempfile.TemporaryDirectory(dir=folder) as work:
            generator = ca.CodeGenerator("lib.c", {"with_header": False})
            for function in functions:
                generator.add(function)
            generator.generate(work + os.sep)
            subprocess.run(["gcc", flags, "-fPIC", "-shared", "lib.c", "-o", "lib.so"],
                           cwd=work, check=True, capture_output=True)
            os.replace(Path(work) / "lib.so", path)
    return {f.name(): ca.external(f.name(), str(path)) for f in functions}
