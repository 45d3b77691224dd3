"""Memory of this process as the kernel counts it (Linux /proc), and a cap on its growth.

The worker memory limit (UNDERTOW_WORKER_MEMORY_MB) bounds how far a worker's address
space may grow beyond its size after start-up; `bench/capacity.py` measures plans in the
same unit, so the up-front estimate (`app.capacity`) and the enforced limit agree.
"""

from __future__ import annotations

import math
import resource
from pathlib import Path

MB = 2**20
_STATUS = Path("/proc/self/status")


def status_mb(field: str) -> float:
    """A memory line of /proc/self/status in MB ("VmSize", "VmPeak", "VmRSS", "VmHWM");
    NaN where the kernel has no such file (not Linux)."""
    try:
        lines = _STATUS.read_text().splitlines()
    except OSError:
        return float("nan")
    for line in lines:
        name, _, value = line.partition(":")
        if name == field:
            return int(value.split()[0]) * 1024 / MB
    return float("nan")


def limit_growth(megabytes: float) -> None:
    """Cap this process's address space (RLIMIT_AS) at its current size plus `megabytes`:
    an allocation beyond it fails (MemoryError in Python, std::bad_alloc in C++).
    Child processes inherit the cap. No-op where the size cannot be read."""
    size = status_mb("VmSize")
    if math.isnan(size):  # not Linux
        return
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    soft = int((size + megabytes) * MB)
    if hard != resource.RLIM_INFINITY:
        soft = min(soft, hard)
    resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
