"""A throwaway PostgreSQL server for tests and benchmarks: a new cluster in a temporary
folder, listening on 127.0.0.1 at a free port, trusting local connections, without fsync
(its data does not outlive it), removed when stopped.

It needs the server's binaries (Debian: `apt-get install postgresql`, found under
/usr/lib/postgresql/VERSION/bin, or at $UNDERTOW_PG_BIN). `initdb` refuses to run as root,
so as root the cluster runs as the `postgres` user through `runuser`.
"""

from __future__ import annotations

import contextlib
import glob
import itertools
import os
import pwd
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Self

from testbed.service import free_port

USER = "undertow"  # the cluster's superuser
START_TIMEOUT = 60.0  # [s]


def binaries() -> Path | None:
    """The folder of initdb and pg_ctl ($UNDERTOW_PG_BIN, else Debian's newest), or None."""
    given = os.environ.get("UNDERTOW_PG_BIN")
    candidates = [given] if given else sorted(glob.glob("/usr/lib/postgresql/*/bin"),
                                              key=lambda p: int(Path(p).parent.name))[::-1]
    for folder in candidates:
        if folder and (Path(folder) / "initdb").exists() and (Path(folder) / "pg_ctl").exists():
            return Path(folder)
    return None


def missing() -> str | None:
    """Why no throwaway server can start here, or None when one can."""
    if binaries() is None:
        return ("PostgreSQL server binaries not found (initdb, pg_ctl under "
                "/usr/lib/postgresql/*/bin or $UNDERTOW_PG_BIN); `make test` installs "
                "Debian's postgresql package when run as root")
    if os.geteuid() == 0:
        try:
            pwd.getpwnam("postgres")
        except KeyError:
            return "running as root without a `postgres` user to run the server as"
    return None


class PostgresServer:
    """A throwaway cluster; `url(name)` addresses one of its databases."""

    def __init__(self) -> None:
        found = binaries()
        if found is None:
            raise RuntimeError(missing())
        self.bin: Path = found
        self.port = free_port()
        self.root = Path(tempfile.mkdtemp(prefix="undertow-pg-"))
        self.data, self.log = self.root / "data", self.root / "server.log"
        self._as_postgres = os.geteuid() == 0
        self.options = (f"-c listen_addresses=127.0.0.1 -c port={self.port} "
                        f"-c unix_socket_directories={self.root} -c fsync=off "
                        "-c synchronous_commit=off -c full_page_writes=off "
                        "-c max_connections=200")

    def _run(self, *command: str) -> None:
        prefix = ["runuser", "-u", "postgres", "--"] if self._as_postgres else []
        subprocess.run([*prefix, *command], check=True, stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE, timeout=START_TIMEOUT)

    def start(self) -> Self:
        if self._as_postgres:
            account = pwd.getpwnam("postgres")
            os.chown(self.root, account.pw_uid, account.pw_gid)
        self._run(str(self.bin / "initdb"), "-D", str(self.data), "-U", USER, "--auth=trust",
                  "--encoding=UTF8", "--no-sync")
        self._run(str(self.bin / "pg_ctl"), "-D", str(self.data), "-l", str(self.log),
                  "-o", self.options, "-w", "-t", str(int(START_TIMEOUT)), "start")
        return self

    def url(self, database: str = "postgres") -> str:
        return f"postgresql://{USER}@127.0.0.1:{self.port}/{database}"

    def create_database(self, name: str) -> str:
        """A new empty database `name`; its URL."""
        import psycopg

        with psycopg.connect(self.url(), autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def restart(self, mode: str = "fast") -> None:
        """`pg_ctl restart -m MODE`: every connection is closed, the server starts again
        on the same port with the same data."""
        self._run(str(self.bin / "pg_ctl"), "-D", str(self.data), "-l", str(self.log),
                  "-m", mode, "-w", "-t", str(int(START_TIMEOUT)), "restart")

    def halt(self) -> None:
        """Stop the server (`pg_ctl stop -m fast`), keeping its data for `resume`."""
        self._run(str(self.bin / "pg_ctl"), "-D", str(self.data), "-m", "fast", "-w", "stop")

    def resume(self) -> None:
        """Start a halted server again with the options it had."""
        self._run(str(self.bin / "pg_ctl"), "-D", str(self.data), "-l", str(self.log),
                  "-o", self.options, "-w", "-t", str(int(START_TIMEOUT)), "start")

    def stop(self) -> None:
        """Stop the server at once and remove its folder."""
        with contextlib.suppress(subprocess.SubprocessError, OSError):
            self._run(str(self.bin / "pg_ctl"), "-D", str(self.data), "-m", "immediate",
                      "-w", "stop")
        shutil.rmtree(self.root, ignore_errors=True)

    def __enter__(self) -> Self:
        try:
            return self.start()
        except BaseException:
            self.stop()
            raise

    def __exit__(self, *exc) -> None:
        self.stop()


_names = itertools.count()


def unique_name(prefix: str = "t") -> str:
    """A database name no other call in this process gets."""
    return f"{prefix}_{os.getpid()}_{next(_names)}"
