"""A node's registration with the queue engine on PostgreSQL: one procrastinate worker per
supervisor (a worker node, or a server with solver processes of its own), named by the
node's `workers` row (`engine_worker`, schema step 10).

Its heartbeat (procrastinate's `last_heartbeat`, by the database's clock) is the one record
of the node's liveness: the node's own heartbeat renews it every `HEARTBEAT` seconds, each
renewal of its running claims renews it too, `GET /v1/workers` lists the node by it, and
every job the node's solver processes claim names it as its engine worker, so that a claim
runs out when its node went silent for the claim's lease. The `workers` row keeps what the
engine does not: the node's name, processes, busy ones and start. Its `seen` stays NULL
(rows of nodes of earlier versions, which write it and hold a registration per claim, are
listed by it). A solver process's claim names its node by the process's worker name,
"{node}/{slot}/{tag}" (a name without that form is a node of its own).
"""

from __future__ import annotations

import builtins
import time

from app.store.base import WorkerRecord
from app.store.postgres_sql import PostgresSql

FORGOTTEN = 3600.0
"""[s] a node silent this long is forgotten (its row and its registration deleted)."""
_REGISTRATION = (
    "SELECT p.id FROM workers w JOIN procrastinate_workers p ON p.id = w.engine_worker "
    "WHERE w.name = %s FOR KEY SHARE OF p")
"""The node's registration, kept from being deleted until the transaction ends."""


def node_of(worker: str) -> str:
    """The node whose solver process is named `worker` ("{node}/{slot}/{tag}")."""
    parts = worker.rsplit("/", 2)
    return parts[0] if len(parts) == 3 else worker


class PostgresNodes(PostgresSql):
    """The heartbeats and listing of nodes on PostgreSQL: the engine's registrations."""

    def _registration(self, node: str, started: float | None = None) -> int:
        """The engine registration of `node` (in the caller's transaction), made when it
        has none, or none any more (removed as a node of an earlier version settles the
        claims of a silent node); the node's row is locked while it is made, so that two
        processes of one node make one. `started` [s]: the start of a new row."""
        rows = self._rows(_REGISTRATION, (node,))
        if rows:
            return int(rows[0][0])
        self._rows("INSERT INTO workers (name, processes, busy, started) VALUES (%s, 0, 0, %s) "
                   "ON CONFLICT (name) DO NOTHING", (node, started or time.time()))
        self._rows("SELECT 1 FROM workers WHERE name = %s FOR UPDATE", (node,))
        rows = self._rows(_REGISTRATION, (node,))
        if rows:  # made by another process of the node meanwhile
            return int(rows[0][0])
        [(registered,)] = self._rows("SELECT worker_id FROM procrastinate_register_worker_v1()")
        self._rows("UPDATE workers SET engine_worker = %s WHERE name = %s", (registered, node))
        return int(registered)

    def heartbeat(self, name: str, processes: int, busy: int, started: float) -> None:
        """The node's registration renewed (made if missing), its row's counts written;
        then the nodes silent for `FORGOTTEN` seconds forgotten."""
        with self._transaction():
            registered = self._registration(name, started)
            self._rows("SELECT procrastinate_update_heartbeat_v1(%s)", (registered,))
            self._rows("UPDATE workers SET processes = %s, busy = %s, started = %s "
                       "WHERE name = %s", (processes, busy, started, name))
        gone = self._rows(
            "DELETE FROM workers w WHERE w.seen < %(old)s OR (w.seen IS NULL AND COALESCE("
            "(SELECT now() - p.last_heartbeat FROM procrastinate_workers p "
            "WHERE p.id = w.engine_worker), make_interval(secs => %(now)s - w.started)) "
            "> make_interval(secs => %(forgotten)s)) RETURNING w.engine_worker",
            {"old": time.time() - FORGOTTEN, "now": time.time(), "forgotten": FORGOTTEN})
        self._unregister([row[0] for row in gone if row[0] is not None])

    def _unregister(self, registrations: builtins.list[int]) -> None:
        """procrastinate's unregistration of each of `registrations`."""
        if registrations:
            self._rows("SELECT procrastinate_unregister_worker_v1(id) FROM unnest(%s::bigint[]) "
                       "AS ids(id)", (registrations,))

    def forget_worker(self, name: str) -> None:
        """The node's row and its registration deleted (it stopped)."""
        with self._transaction():
            gone = self._rows("DELETE FROM workers WHERE name = %s RETURNING engine_worker",
                              (name,))
            self._unregister([row[0] for row in gone if row[0] is not None])

    def workers(self, since: float) -> builtins.list[WorkerRecord]:
        """The nodes whose registration's heartbeat (or, for a node of an earlier version,
        its row's `seen`) is not older than `since`; their heartbeats' ages are taken by
        the database's clock and given as times of this process's clock."""
        now = time.time()
        rows = self._rows(
            "SELECT w.name, w.processes, w.busy, w.started, COALESCE(%s - EXTRACT(EPOCH FROM "
            "now() - p.last_heartbeat)::double precision, w.seen) FROM workers w "
            "LEFT JOIN procrastinate_workers p ON p.id = w.engine_worker ORDER BY w.name",
            (now,))
        return [WorkerRecord(*row) for row in rows if row[4] is not None and row[4] >= since]
