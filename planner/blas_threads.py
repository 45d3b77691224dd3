"""One BLAS thread in each solver process.

Ipopt's linear solver, MUMPS, does its dense work in the OpenBLAS that CasADi's wheel
bundles (`libcasadi-tp-openblas`, loaded with the Ipopt plugin), which by default runs a
thread on every core of the machine. The planner already spreads its solves over the
cores, one process per core it holds (`planner.ocp.cores`: a plan and its companion, the
service's solver workers), so those threads contend for cores that other solves hold, and
OpenBLAS' idle threads spin while they wait. Where MUMPS factors large fronts (its pivots
delayed on the ill-conditioned KKT matrix of a refined co-design solve far from a motion)
an iteration took several times as long with them, more than half of it in the kernel;
where the fronts are small (the seed arm at N = 100) the thread count makes no
difference (docs/benchmarks.md, "Cost of an iteration on the seed arm", and the hard
suite's configuration "BLAS threads").

An OPENBLAS_NUM_THREADS set in the environment is left as it is: OpenBLAS reads it itself.
"""

from __future__ import annotations

import ctypes
import functools
import os
from pathlib import Path

import casadi as ca

ENVIRONMENT = "OPENBLAS_NUM_THREADS"
LIBRARY = "libcasadi-tp-openblas.so.0"
"""CasADi's own OpenBLAS, next to its Python package (Linux wheels)."""


@functools.cache
def limit() -> bool:
    """Load CasADi's Ipopt plugin and, unless the environment sets OPENBLAS_NUM_THREADS,
    run the OpenBLAS it brings on one thread. Whether it did (False: the environment
    decides, or this platform's CasADi has no such library). Once per process: a forked
    companion keeps the setting."""
    if ENVIRONMENT in os.environ:
        return False
    ca.load_nlpsol("ipopt")
    path = Path(ca.__file__).resolve().parent / LIBRARY
    if not path.exists():
        return False
    ctypes.CDLL(str(path)).openblas_set_num_threads(1)
    return True


def threads() -> int | None:
    """The threads CasADi's OpenBLAS runs (None without the library)."""
    path = Path(ca.__file__).resolve().parent / LIBRARY
    return int(ctypes.CDLL(str(path)).openblas_get_num_threads()) if path.exists() else None
