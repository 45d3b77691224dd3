"""The PostgreSQL job store, queued by procrastinate: one database shared by API servers
and workers on any number of machines (UNDERTOW_DB_URL).

procrastinate's `procrastinate_jobs` rows are the queue, and their status is where each
job is; undertow's `jobs` rows keep what the engine does not (progress, cancel flag, plan,
history, batches, limits) and the API's status, which the database derives from the
engine's (`app.store.postgres_status`) and no statement here writes. Each job has one
engine job (queue: the job's owner, task `TASK`), linked by the table `undertow_queue`,
and every transition writes undertow's record and moves the engine job in one
transaction:

- claim: procrastinate's `fetch_job` (oldest by id, `FOR UPDATE SKIP LOCKED`, its retry
  time come) for the claiming node's engine registration (`app.store.postgres_nodes`),
  whose heartbeat is the node's liveness and the claim's lease;
- pickup: procrastinate's trigger NOTIFYs its channel when a job is deferred (inserted);
  this store NOTIFYs it when it queues a job again, which the trigger does not see: at
  once (released by its worker, retried by id) with an empty payload, after a pause (an
  infrastructure failure: a dead worker, a stalled claim) with the pause
  (`app.store.postgres_listener.due_in`), so that idle solver processes, which LISTEN
  there, look for it when the pause has passed rather than at their next poll;
- renewal: procrastinate's `update_heartbeat` of the node's registration;
- stalled jobs: procrastinate's `select_stalled_jobs_by_heartbeat` rewritten (`_STALLED`)
  to time each claim out by its own lease (the one it stored) rather than one for all:
  the claims whose node went silent (a node's registration stays for its next heartbeat;
  one a node of an earlier version made for a single claim is removed as the job is
  requeued);
- retries: procrastinate's `retry_job` queues the job again at its retry time (the pause of
  undertow's `RetryPolicy`), its `finish_job` ends it (failed, a dead letter, or aborted
  when it was cancelled), its `cancel_job` cancels a queued one and flags a running one.

What undertow keeps is its record of each transition (history, counts, dead-letter errors:
`app.store.sql`) and the lease each claim stored, by which it is judged; the columns in
which the SQLite store keeps its queue (a claim's end, `lease_until`, and a requeued job's
retry time, `not_before`) stay NULL, as the engine keeps both. Its connections and the
statements PostgreSQL runs in transactions of their own are `app.store.postgres_sql`'s;
the supervisor runs each solve in a process of its own. The engine's schema
(procrastinate's `schema.sql` of the pinned version) and the link table are created when
the store opens a database that lacks them. Jobs written by versions before procrastinate
queued them are taken over: the queued ones get an engine job then, and any left without
one (queued by a server of such a version during a rolling upgrade) at each look for
stalled jobs; one they had claimed runs out by the lease its claim wrote. A claim's lease
is its process's `lease` [s] (UNDERTOW_LEASE), stored with the claim and counted by the
database's clock from the last renewal; every process judges a claim by that stored lease,
so processes with different leases share a database without requeueing each other's
healthy claims.
"""

from __future__ import annotations

import builtins
import datetime
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import psycopg
from procrastinate import SyncPsycopgConnector, exceptions, manager, schema
from procrastinate import jobs as engine_jobs
from procrastinate.sql import queries

from app.store.base import FINAL, SILENCE, JobRecord, JobStatus, RetryPolicy
from app.store.postgres_listener import PostgresListener, due_in
from app.store.postgres_nodes import PostgresNodes, node_of
from app.store.postgres_status import install, refuse_beside_earlier_nodes
from app.store.sql import COLUMNS, LEASE_RAN_OUT

TASK = "undertow.plan"
"""The procrastinate task name of every engine job (nothing runs it as a task)."""
CHANNEL = next(iter(manager.get_channel_for_queues(None)))
"""procrastinate's channel notified whenever a job of any queue is deferred."""
ENDED: dict[str, str] = {"succeeded": "succeeded", "failed": "failed", "cancelled": "aborted"}
"""A job's final status -> its engine job's (a job cancelled while queued: `cancelled`)."""
_LINK = ("CREATE TABLE IF NOT EXISTS undertow_queue ("
         "job_id TEXT PRIMARY KEY REFERENCES jobs (id) ON DELETE CASCADE, "
         "queue_id BIGINT NOT NULL UNIQUE REFERENCES procrastinate_jobs (id) ON DELETE CASCADE)")
_UNCLAIMED = "(status = 'running' AND worker IS NULL)"
"""A job whose engine job was just fetched: its status, derived from the fetch, reads
`running`, and no claim is written on it yet."""
_ENGINE_LOCK = 0x756E6475  # advisory lock key held while the engine's schema is installed
_LINKED = ("FROM jobs j JOIN undertow_queue m ON m.job_id = j.id "
           "JOIN procrastinate_jobs q ON q.id = m.queue_id")
_STALLED = (  # procrastinate's select_stalled_jobs_by_heartbeat, each claim by its own lease,
    # on procrastinate's tables (procrastinate_workers.last_heartbeat, jobs' worker_id)
    "SELECT q.id " + _LINKED + " LEFT JOIN procrastinate_workers w ON w.id = q.worker_id "
    "WHERE q.status = 'doing' AND q.task_name = '" + TASK + "' AND "
    "EXTRACT(EPOCH FROM now() - pg_postmaster_start_time()) >= COALESCE(j.lease, :lease) "
    "AND (q.worker_id IS NULL OR w.last_heartbeat < now() - make_interval(secs => "
    "GREATEST(LEAST(COALESCE(j.lease, :lease), :silence), COALESCE(j.lease, :lease) - :ahead)"
    "))")
"""The engine jobs whose claim's registration is gone or was silent for longer than the
lease the claim stored (`:lease`, the looking process's, for a claim that stored none),
`:ahead` [s] later than now, and silent now for `:silence` s at least (its whole lease if
shorter: `SILENCE`)."""


@contextmanager
def _database_errors() -> Iterator[None]:
    """procrastinate's wrapped database errors raised as psycopg's own (so that the store
    reports an unreachable database as StoreUnavailable)."""
    try:
        yield
    except exceptions.ConnectorException as exc:
        raise (exc.__cause__ or exc) from None


def _utc(seconds: float) -> datetime.datetime:
    """Unix seconds as an aware datetime (what procrastinate's times are)."""
    return datetime.datetime.fromtimestamp(seconds, datetime.UTC)


class PostgresJobStore(PostgresNodes):
    """Jobs in a PostgreSQL database at `url` ("postgresql://user:password@host:port/db")
    queued by procrastinate; `lease` [s]: how long a claim holds after its last renewal
    (the heartbeat timeout). `pool_size`, `timeout`: `PostgresSql`'s."""

    QUEUE_COLUMNS = False  # procrastinate keeps the status, claims' heartbeats, retry times

    def __init__(self, url: str, pool_size: int = 4, timeout: float = 10.0,
                 policy: RetryPolicy | None = None, lease: float = 60.0):
        self.lease = lease
        self._engine = SyncPsycopgConnector()  # runs on this store's connections only
        super().__init__(url, pool_size, timeout, policy)

    def __getstate__(self) -> dict[str, Any]:
        return {**super().__getstate__(), "lease": self.lease}

    def __setstate__(self, state: dict[str, Any]) -> None:
        super().__setstate__(state)
        self.lease, self._engine = state["lease"], SyncPsycopgConnector()

    def _run(self, name: str, **params: Any) -> builtins.list[dict[str, Any]]:
        """The rows of procrastinate's statement `name` in this thread's transaction."""
        with self._connection() as conn, _database_errors():
            return self._engine.execute_query_all_with_connection(conn, queries[name], **params)

    def _migrate(self) -> None:
        """undertow's migrations (refused beside nodes too early for a derived status:
        `app.store.postgres_status`), then the engine's schema, the link table and the
        status's derivation where they are missing, and an engine job for every queued
        job that has none."""
        with self._transaction():
            refuse_beside_earlier_nodes(self._rows, self.lease, f"the job store "
                                        f"({self._where()})")
        super()._migrate()
        try:
            with self._transaction() as conn:
                conn.execute("SELECT pg_advisory_xact_lock(%s)", (_ENGINE_LOCK,))
                if self._run("check_connection")[0]["check"] is None:
                    conn.execute(schema.SchemaManager.get_schema())
                conn.execute(_LINK)
                install(self._rows)
                self._adopt()
        except psycopg.Error as exc:
            raise self._unavailable(exc) from exc

    def _adopt(self) -> None:
        """An engine job for every queued job that has none (stored by a version before
        procrastinate queued the jobs, or by a server of one during a rolling upgrade),
        oldest first."""
        self._defer([(job_id, owner) for job_id, owner in self._rows(
            "SELECT id, owner FROM jobs WHERE status = 'queued' AND NOT EXISTS "
            "(SELECT 1 FROM undertow_queue WHERE job_id = jobs.id) ORDER BY created, id")])

    def _defer(self, jobs: builtins.list[tuple[str, str]],
               after: float = 0.0) -> builtins.list[int]:
        """An engine job in the owner's queue for each (job id, owner), linked to it, to
        be claimed no sooner than `after` seconds from now: their ids."""
        if not jobs:
            return []
        start = _utc(time.time() + after) if after > 0.0 else None
        with self._connection() as conn, _database_errors():
            deferred = manager.JobManager(self._engine).batch_defer_jobs(
                [engine_jobs.Job(queue=owner, lock=None, queueing_lock=None, task_name=TASK,
                                 task_kwargs={"job": job_id}, scheduled_at=start)
                 for job_id, owner in jobs], connection=conn)
            with conn.cursor() as cursor:
                cursor.executemany(
                    "INSERT INTO undertow_queue (job_id, queue_id) VALUES (%s, %s) "
                    "ON CONFLICT (job_id) DO UPDATE SET queue_id = EXCLUDED.queue_id",
                    [(job_id, job.id) for (job_id, _), job in zip(jobs, deferred, strict=True)])
        return [int(job.id) for job in deferred if job.id is not None]

    def _settle(self, targets: Mapping[str, JobStatus], pause: bool) -> None:
        """Move the engine jobs of the jobs in `targets` to the status each job takes,
        which the database then derives for the job (`app.store.postgres_status`): one
        queued again is retried (after the policy's pause for its failures when `pause`,
        else at once), a final one ended; a job without one (claimed by a version before
        procrastinate) gets one first. A registration made for its claim alone (by a node
        of an earlier version) is removed, a node's stays and no longer names the job (so
        that deleting it when the node stops locks none of its former jobs, which a fetch
        would skip)."""
        if not targets:
            return
        rows = self._rows(
            "SELECT j.id, j.owner, j.infra_failures, q.id, q.status, "
            "CASE WHEN NOT EXISTS (SELECT 1 FROM workers w WHERE w.engine_worker = q.worker_id) "
            "THEN q.worker_id END "
            "FROM jobs j LEFT JOIN undertow_queue m ON m.job_id = j.id "
            "LEFT JOIN procrastinate_jobs q ON q.id = m.queue_id WHERE j.id = ANY(%s)",
            (builtins.list(targets),))
        self._rows("UPDATE procrastinate_jobs SET worker_id = NULL WHERE status = 'doing' "
                   "AND id = ANY(%s)", ([row[3] for row in rows if row[3] is not None],))
        queued: set[float] = set()
        for job_id, owner, failures, queue_id, engine_status, claim_worker in rows:
            status = targets[job_id]
            delay = self.policy.delay(failures) if pause and status == "queued" else 0.0
            if status == "queued":
                queued.add(delay)
            if queue_id is None:
                [queue_id] = self._defer([(job_id, owner)], delay)
                engine_status = "todo"
            self._move(queue_id, engine_status, status, delay)
            if claim_worker is not None:  # a registration of its claim alone
                self._run("unregister_worker", worker_id=claim_worker)
        self._announce(queued)

    def _move(self, queue_id: int, engine: str, status: JobStatus, delay: float) -> None:
        """The engine transition that takes engine job `queue_id`, now `engine`, to the
        job's new `status` (retried after `delay` [s] when queued again)."""
        if status == "queued" and engine == "doing":
            self._run("retry_job", job_id=queue_id, retry_at=_utc(time.time() + delay),
                      new_priority=None, new_queue_name=None, new_lock=None)
        elif status == "cancelled" and engine == "todo":
            self._run("cancel_job", job_id=queue_id, abort=False, delete_job=False)
        elif status in FINAL and engine in ("todo", "doing"):
            self._run("finish_job", job_id=queue_id, status=ENDED[status], delete_job=False)

    def _announce(self, pauses: set[float]) -> None:
        """NOTIFY idle workers (at commit) of jobs queued again, which procrastinate's
        trigger does not see: once for those claimable now, once for each pause [s]."""
        for delay in sorted(pauses):
            self._rows("SELECT pg_notify(%s, %s)",
                       (CHANNEL, due_in(delay) if delay > 0.0 else ""))

    def create(self, job_id: str, scene: dict[str, Any], owner: str,
               limit: int | None = None, key: str | None = None,
               admission: dict[str, Any] | None = None) -> JobRecord | None:
        with self._transaction():
            record = super().create(job_id, scene, owner, limit, key, admission)
            if record is not None:
                self._defer([(job_id, owner)])
            return record

    def create_batch(self, batch_id: str, spec: dict[str, Any],
                     members: builtins.list[tuple[str, dict[str, Any]]], owner: str,
                     limit: int | None = None,
                     admissions: Sequence[dict[str, Any] | None] | None = None) -> bool:
        with self._transaction():
            if not super().create_batch(batch_id, spec, members, owner, limit, admissions):
                return False
            self._defer([(job_id, owner) for job_id, _ in members])
            return True

    def claim(self, owner: str | None, worker: str, lease_until: float) -> JobRecord | None:
        """procrastinate's fetch, then the claim written on the job (`_UNCLAIMED`)."""
        with self._transaction():
            [row] = self._run("fetch_job", queues=None if owner is None else [owner],
                              worker_id=self._registration(node_of(worker)))
            if row["id"] is None:
                raise psycopg.Rollback()  # nothing written (nor a registration made for it)
            # the engine job is doing, so the job reads running (the database derives it)
            rows = self._write(
                f"UPDATE jobs SET {self._claiming()} WHERE {_UNCLAIMED} AND id = "
                f"(SELECT job_id FROM undertow_queue WHERE queue_id = :queue) RETURNING {COLUMNS}",
                {**self._claim_params(worker, lease_until), "queue": row["id"]})
            if not rows:  # a stray engine job (its job was not queued): end it alone
                self._run("finish_job", job_id=row["id"], status="failed", delete_job=False)
                return None
            return self._record(rows[0])
        return None

    def renew(self, claims: builtins.list[tuple[str, str]],
              lease_until: float) -> dict[str, bool]:
        """A heartbeat of each claim's registration (the lease runs `lease` seconds from
        now; `lease_until` is not used); {job id: cancel requested} of those still held."""
        if not claims:
            return {}
        pairs = ", ".join(["(%s, %s)"] * len(claims))
        rows = self._rows(
            f"SELECT j.id, j.cancel_requested, procrastinate_update_heartbeat_v1(q.worker_id) "
            f"{_LINKED} WHERE j.status = 'running' AND q.status = 'doing' "
            f"AND q.worker_id IS NOT NULL AND (j.id, j.worker) IN (VALUES {pairs})",
            tuple(v for claim in claims for v in claim))
        return {job_id: bool(cancel) for job_id, cancel, _ in rows}

    def expire(self, now: float) -> dict[str, JobStatus]:
        """Requeue the jobs whose claim's registration was silent before `now` for longer
        than the lease the claim stored (none within that lease of a database restart,
        when nobody could renew), whatever lease the looking process has; defer the queued
        jobs that have no engine job yet."""
        restarted = self._rows("SELECT EXTRACT(EPOCH FROM now() - pg_postmaster_start_time())")
        with self._transaction():
            self._adopt()
            ended, params = self._lease_ended(now)  # claimed by a version before
            before = {} if float(restarted[0][0]) < self.lease else self._requeue(
                f"{ended} AND NOT EXISTS (SELECT 1 FROM undertow_queue "
                "WHERE job_id = jobs.id)", params, LEASE_RAN_OUT)
            stalled = [row[0] for row in self._rows(_STALLED, {
                "ahead": now - time.time(), "lease": self.lease, "silence": SILENCE})]
            if not stalled:
                return before
            return {**before, **self._requeue(
                "id IN (SELECT job_id FROM undertow_queue WHERE queue_id = ANY(:stalled))",
                {"stalled": stalled}, LEASE_RAN_OUT)}

    def _requeue(self, condition: str, params: dict[str, Any],
                 reason: str) -> dict[str, JobStatus]:
        with self._transaction():
            done = super()._requeue(condition, params, reason)
            self._settle(done, pause=True)
            return done

    def _release(self, condition: str, params: dict[str, Any]) -> dict[str, JobStatus]:
        with self._transaction():
            released = super()._release(condition, params)
            self._settle(released, pause=False)
            return released

    def finish(self, job_id: str, status: JobStatus, plan: dict[str, Any] | None,
               error: str | None, solution: dict[str, Any] | None = None,
               worker: str | None = None) -> bool:
        with self._transaction():
            if not super().finish(job_id, status, plan, error, solution, worker):
                return False
            self._settle({job_id: status}, pause=False)
            return True

    def fail(self, job_id: str, error: str) -> bool:
        with self._transaction():
            if not super().fail(job_id, error):
                return False
            self._settle({job_id: "failed"}, pause=False)
            return True

    def _abort(self, condition: str, params: tuple) -> None:
        """procrastinate's cancel of the engine jobs of the jobs that meet `condition`: a
        queued one ends cancelled, a running one is flagged for abort."""
        self._rows(f"SELECT procrastinate_cancel_job_v1(q.id, true, false) {_LINKED} "
                   f"WHERE {condition} AND q.status IN ('todo', 'doing')", params)

    def request_cancel(self, job_id: str) -> JobRecord | None:
        with self._transaction():
            record = super().request_cancel(job_id)
            if record is None or not record.cancel_requested:
                return record
            self._abort("j.id = %s", (job_id,))
            return self.get(job_id)

    def cancel_batch(self, batch_id: str) -> bool:
        with self._transaction():
            if not super().cancel_batch(batch_id):
                return False
            self._abort("j.batch = %s AND j.cancel_requested", (batch_id,))
            return True

    def retry(self, job_id: str, owner: str, limit: int | None = None) -> bool:
        """A failed engine job is retried in the new owner's queue; a cancelled or
        aborted one, which procrastinate does not retry, is replaced by a new one."""
        with self._transaction():
            if not super().retry(job_id, owner, limit):
                return False
            row = self._rows(f"SELECT q.id, q.status {_LINKED} WHERE j.id = %s", (job_id,))
            if row and row[0][1] == "failed":
                self._run("retry_job", job_id=row[0][0], retry_at=_utc(time.time()),
                          new_priority=None, new_queue_name=owner, new_lock=None)
                self._announce({0.0})
            else:
                self._defer([(job_id, owner)])
            return True

    def purge(self, before: float, keep: int, size: int | None = None) -> int:
        """undertow's purge, then the ended engine jobs no job links to any more."""
        with self._transaction():
            purged = super().purge(before, keep, size)
            self._rows("DELETE FROM procrastinate_jobs q WHERE q.status IN ('succeeded', "
                       "'failed', 'cancelled', 'aborted') AND NOT EXISTS (SELECT 1 FROM "
                       "undertow_queue m WHERE m.queue_id = q.id)")
            return purged

    def listen(self) -> PostgresListener:
        """A connection of its own on procrastinate's channel of deferred jobs."""
        return PostgresListener(self.url, self.timeout, CHANNEL)
