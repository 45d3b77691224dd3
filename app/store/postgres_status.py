"""A job's status on PostgreSQL, derived by the database from its engine job's.

procrastinate's `procrastinate_jobs.status` is the queue's one record of where a job is;
the API's `jobs.status` (five values) follows it by a trigger, in the transaction that
changes it, and no statement of undertow writes it (a new row starts `queued`, the
column's default from schema step 11):

| engine job | todo | doing | succeeded | failed | cancelled, aborted |
|---|---|---|---|---|---|
| job | queued | running | succeeded | failed | cancelled |

The job follows along the API's own transitions only: into `queued` from any status (a
release, a requeue, a retry), into `running` from `queued` (a claim), into a final status
from `queued` or `running`. An engine job that moves otherwise (a stray one, fetched for
a job that is not queued, which the claim then ends) leaves the job as it was. The
trigger fires on an engine job's change of status and on a job's link to a new engine job
(`undertow_queue`: a new job, a retry of a cancelled one).

Nodes of releases before da7fea7 wrote each status themselves and claimed only jobs that
read `queued`; beside this trigger their claims would fail, so a process does not install
it while such a node is alive (`EarlierNodes`): they write a heartbeat in `workers.seen`,
which later nodes leave NULL. Nodes of da7fea7 up to this one's previous release write the
status as the trigger derives it, and claim a job that reads `running` with no claim
written, so they run beside it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from app.store.base import EarlierNodes

TRIGGERS = ("undertow_status_of_engine", "undertow_status_of_link")
"""The trigger on `procrastinate_jobs` and the one on `undertow_queue`."""

_API_STATUS = """
CREATE OR REPLACE FUNCTION undertow_api_status(engine procrastinate_job_status)
RETURNS text LANGUAGE sql IMMUTABLE AS $$
  SELECT CASE engine WHEN 'todo' THEN 'queued' WHEN 'doing' THEN 'running'
    WHEN 'aborting' THEN 'running' WHEN 'aborted' THEN 'cancelled' ELSE engine::text END
$$"""
"""The API's status of an engine job's (`aborting`: procrastinate's legacy abort flag)."""
_FOLLOW = """
CREATE OR REPLACE FUNCTION undertow_follow_engine() RETURNS trigger LANGUAGE plpgsql AS $$
DECLARE
  engine_id bigint;
BEGIN
  IF TG_TABLE_NAME = 'undertow_queue' THEN
    engine_id := NEW.queue_id;
  ELSE
    engine_id := NEW.id;
  END IF;
  UPDATE jobs j SET status = undertow_api_status(q.status)
  FROM undertow_queue m JOIN procrastinate_jobs q ON q.id = m.queue_id
  WHERE m.queue_id = engine_id AND j.id = m.job_id
    AND j.status <> undertow_api_status(q.status)
    AND (q.status = 'todo' OR (q.status IN ('doing', 'aborting') AND j.status = 'queued')
         OR (q.status NOT IN ('todo', 'doing', 'aborting')
             AND j.status IN ('queued', 'running')));
  RETURN NULL;
END
$$"""
"""The job of the changed engine job (or link) takes the engine job's status, along the
API's transitions only."""
_INSTALL = (
    _API_STATUS, _FOLLOW,
    f"CREATE TRIGGER {TRIGGERS[0]} AFTER UPDATE OF status ON procrastinate_jobs "
    "FOR EACH ROW WHEN (OLD.status IS DISTINCT FROM NEW.status) "
    "EXECUTE FUNCTION undertow_follow_engine()",
    f"CREATE TRIGGER {TRIGGERS[1]} AFTER INSERT OR UPDATE OF queue_id ON undertow_queue "
    "FOR EACH ROW EXECUTE FUNCTION undertow_follow_engine()",
)

Rows = Callable[..., list[tuple[Any, ...]]]
"""Runs one statement (with optional parameters) in the caller's transaction: its rows."""


def derived(rows: Rows) -> bool:
    """Whether the database derives the jobs' status (both triggers installed)."""
    [(count,)] = rows("SELECT COUNT(*) FROM pg_trigger WHERE tgname = ANY(%s)",
                      (list(TRIGGERS),))
    return bool(count == len(TRIGGERS))


def refuse_beside_earlier_nodes(rows: Rows, within: float, where: str) -> None:
    """EarlierNodes when the status is not derived yet and a node of a release before
    da7fea7 wrote its heartbeat (`workers.seen`, by its own clock) in the last `within`
    seconds of the database's clock."""
    if derived(rows):
        return
    [(table,)] = rows("SELECT to_regclass('workers') IS NOT NULL")
    if not table:
        return
    names = [name for (name,) in rows(
        "SELECT name FROM workers WHERE seen >= EXTRACT(EPOCH FROM now()) - %s "
        "ORDER BY name", (within,))]
    if names:
        raise EarlierNodes(
            f"{where}: node(s) {', '.join(names)} of a release before da7fea7 are running "
            "on it, which claim only jobs whose status reads queued; this version derives "
            "each job's status from the queue engine's and would end their claims failed. "
            "Replace them by nodes of release cc6413d or later first (docs/deploy.md, "
            "Upgrading a cluster), then start this one")


def install(rows: Rows) -> None:
    """The status's derivation, when it is missing (in the caller's transaction, after
    the engine's schema and the link table): the functions, then both triggers."""
    if derived(rows):
        return
    for trigger, table in zip(TRIGGERS, ("procrastinate_jobs", "undertow_queue"), strict=True):
        rows(f"DROP TRIGGER IF EXISTS {trigger} ON {table}")
    for statement in _INSTALL:
        rows(statement)
