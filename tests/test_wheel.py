"""The wheel holds the library and the service, and nothing of what tests and benchmarks
share (testbed/: the generated suites and their stored solves).

Built by pip from a copy of the source tree (the build writes into its source), its build
backend installed from the package index as `make install` installs it (about 5 s).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SUITES = ROOT / "testbed" / "suites"
LOCAL = shutil.ignore_patterns(".git", ".venv*", "__pycache__", "build", "dist", "*.egg-info",
                               ".*_cache", ".hypothesis", "var", "jit_tmp*", "tmp_casadi_*")
"""What a working tree holds besides its sources: left out of the copy that is built."""


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """The files of the wheel built from this tree, by name."""
    source = tmp_path_factory.mktemp("source") / "undertow"
    shutil.copytree(ROOT, source, ignore=LOCAL)
    out = tmp_path_factory.mktemp("wheel")
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet",
                           "--wheel-dir", str(out), str(source)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    (path,) = out.glob("undertow-*.whl")
    with zipfile.ZipFile(path) as built:
        return {name: built.read(name) for name in built.namelist()}


def test_the_wheel_holds_the_library_and_the_service(wheel: dict[str, bytes]) -> None:
    tops = {name.split("/")[0] for name in wheel if ".dist-info/" not in name}
    assert tops == {"planner", "app"}
    assert {"planner/__init__.py", "planner/ocp/planner.py", "planner/examples.py",
            "app/main.py", "app/static/index.html"} <= set(wheel)


def test_the_wheel_holds_no_suite_nor_its_stored_data(wheel: dict[str, bytes]) -> None:
    """No file named for a suite, and none with the contents of a suite's module or data
    file, wherever it might have been copied to."""
    assert [name for name in wheel if "suite" in name.lower()] == []
    suites = {path.read_bytes(): path.relative_to(ROOT) for path in SUITES.rglob("*")
              if path.is_file() and path.suffix in (".py", ".json")}
    assert len(suites) >= 6 and any(path.suffix == ".json" for path in suites.values())
    assert {name: str(suites[data]) for name, data in wheel.items() if data in suites} == {}
