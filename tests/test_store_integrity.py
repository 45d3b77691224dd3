"""The SQLite store's integrity checks (`app.store.sqlite_integrity`): damage to the file
under a running service is found before the next job is accepted, even where the
write-ahead log still holds newer copies of the pages it reads; a first page overwritten
while the log holds it is written back at the next start; a store that fails its check is
refused at start, naming the restore command; the quick check runs only when the file
changed or a statement failed, the full one on its cadence."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.store import SqliteJobStore, StoreDamaged, StoreUnavailable
from app.store.sqlite_file import HEADER

PAD = {"pad": "x" * 500}


def filled(path: Path, jobs: int) -> SqliteJobStore:
    """A store of `jobs` jobs of 500 bytes each, all in its main file (its log empty)."""
    store = SqliteJobStore(path)
    for k in range(jobs):
        store.create(f"j{k}", PAD, "host")
    store.checkpoint(final=True)
    return store


def overwrite(path: Path, start: int, end: int | None = None) -> None:
    """Overwrite the file's bytes from `start` to `end` (its end) in place, as `dd
    conv=notrunc` would: same inode, same size."""
    end = path.stat().st_size if end is None else end
    with open(path, "r+b") as file:
        file.seek(start)
        file.write(b"\xa5" * (end - start))


def test_pages_overwritten_under_newer_copies_in_the_log_refuse_every_new_job(tmp_path):
    path = tmp_path / "db.sqlite3"
    store = filled(path, 60)
    for k in range(20):  # their pages, and the paths to them, are in the log now
        store.create(f"recent-{k}", PAD, "host")
    overwrite(path, 4096)  # every page of the main file after the first
    with pytest.raises(StoreDamaged, match="no new job is accepted"):
        store.create("after", PAD, "host")
    for accept in (lambda: store.create("again", PAD, "host"), store.check,
                   lambda: store.create_batch("b", {}, [("b-0", PAD)], "host"),
                   lambda: store.retry("j0", "host")):
        with pytest.raises(StoreDamaged, match="undertow restore BACKUP"):
            accept()
    store.close()
    with pytest.raises(StoreDamaged, match=r"refusing to start on it\. Restore the last backup: "
                                           r"`undertow restore BACKUP`"):
        SqliteJobStore(path)


def test_a_first_page_overwritten_while_the_log_holds_it_is_written_back(tmp_path):
    path = tmp_path / "db.sqlite3"
    store = filled(path, 20)
    for k in range(20):  # new pages: the first page, which counts them, is in the log
        store.create(f"recent-{k}", PAD, "host")
    overwrite(path, 0, 100)  # SQLite's header
    with pytest.raises(StoreDamaged, match="overwritten while the service ran"):
        store.create("after", PAD, "host")
    again = SqliteJobStore(path)  # a restart: without the killed server's connections
    assert path.read_bytes()[:16] == HEADER
    assert again.count_by_status()["queued"] == 40 and again.get("after") is None
    again.create("after", PAD, "host")


def test_a_first_page_overwritten_with_no_copy_in_the_log_refuses_the_start(tmp_path):
    path = tmp_path / "db.sqlite3"
    filled(path, 20).close()
    overwrite(path, 0, 100)
    with pytest.raises(StoreDamaged, match="file is not a database.*undertow restore BACKUP"):
        SqliteJobStore(path)


def test_the_quick_check_runs_when_the_file_changed_or_a_statement_failed(tmp_path, monkeypatch):
    store = SqliteJobStore(tmp_path / "db.sqlite3")
    ran: list[str] = []
    check = store.integrity._findings
    monkeypatch.setattr(store.integrity, "_findings",
                        lambda pragma: ran.append(pragma) or check(pragma))
    for k in range(5):  # into the log: the main file stays as it was
        store.create(f"j{k}", PAD, "host")
    store.check()
    assert ran == []
    store.checkpoint()  # the main file is written
    store.create("after-checkpoint", PAD, "host")
    store.create("and-another", PAD, "host")
    assert ran == ["quick_check"]
    with pytest.raises(StoreUnavailable):
        store._rows("SELECT * FROM no_such_table")
    store.create("after-a-failure", PAD, "host")
    assert ran == ["quick_check"] * 2


def test_the_full_check_runs_on_its_cadence(tmp_path, monkeypatch):
    store = SqliteJobStore(tmp_path / "db.sqlite3", integrity_interval=0.0)
    ran: list[str] = []
    check = store.integrity._findings
    monkeypatch.setattr(store.integrity, "_findings",
                        lambda pragma: ran.append(pragma) or check(pragma))
    store.create("a", PAD, "host")
    store.verify()
    assert ran == ["integrity_check"] * 2
