"""A client of a replanning session (docs/api.md, "Replanning sessions"): open a session on
a finished plan job, send the arm's measured state at a fixed rate, and between updates
apply the last update's torque with its LQR correction.

    python -m clients.session --url http://127.0.0.1:8000 --plan JOB_ID [--key KEY]

run as a script, it replays the plan's own states as the "measurements" (an arm that
follows the plan exactly) and prints each update's status and round trip; a controller
gives its sensor's state to `Session.update` instead, and `command` to its servo loop.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import httpx
import numpy as np


def _at(coefficients: list, s: float) -> np.ndarray:
    """One interval's polynomial (powers x columns, ascending powers of s) at s."""
    c = np.asarray(coefficients, float)
    return (s ** np.arange(c.shape[0])) @ c


def command(update: dict[str, Any], t: float, x: np.ndarray) -> np.ndarray:
    """The torque [N m] (n_active,) an update asks for at time t [s] along the plan for the
    measured state x = (q, dq) (2n,): its delivered torque less K_k (x - x_plan(t)) on the
    interval k holding t, x_plan the update's planned angles and rates (`states`)."""
    breaks = np.asarray(update["torque"]["breaks"])
    k = int(np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, len(breaks) - 2))
    s = float(np.clip((t - breaks[k]) / (breaks[k + 1] - breaks[k]), 0.0, 1.0))
    tau = _at(update["torque"]["coefficients"][k], s)
    if update["gains"] is None:
        return tau
    states = update["states"]
    planned = np.concatenate([_at(states["q"][k], s), _at(states["dq"][k], s)])
    return tau - np.asarray(update["gains"][k]) @ (np.asarray(x, float) - planned)


class Session:
    """One replanning session on a server, over one kept-alive connection."""

    def __init__(self, client: httpx.Client, plan_id: str, **options: Any):
        answer = client.post("/v1/sessions", json={"plan": plan_id, **options})
        answer.raise_for_status()
        self.client, self.info = client, answer.json()
        self.id: str = self.info["id"]
        self.current: dict[str, Any] = self.info["warm_up"]

    def update(self, t: float, q: list[float], dq: list[float],
               **options: Any) -> dict[str, Any]:
        """Send a measured state; the answer (kept as `current` unless it is a fallback,
        whose last plan stands)."""
        answer = self.client.post(f"/v1/sessions/{self.id}/updates",
                                  json={"t": t, "q": q, "dq": dq, **options})
        answer.raise_for_status()
        report = answer.json()
        if not report["fallback"]:
            self.current = report
        return report

    def command(self, t: float, x: np.ndarray) -> np.ndarray:
        """The torque for the measured state x at time t, from the current update."""
        return command(self.current, t, x)

    def close(self) -> None:
        self.client.delete(f"/v1/sessions/{self.id}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m clients.session", description=__doc__)
    parser.add_argument("--url", default="http://127.0.0.1:8000")
    parser.add_argument("--plan", required=True, help="id of a plan job that has its plan")
    parser.add_argument("--key", default=None, help="the server's API key, if it has one")
    parser.add_argument("--updates", type=int, default=20)
    args = parser.parse_args(argv)
    headers = {} if args.key is None else {"X-API-Key": args.key}
    with httpx.Client(base_url=args.url, headers=headers, timeout=30.0) as client:
        plan = client.get(f"/v1/plans/{args.plan}")
        plan.raise_for_status()
        nodes = plan.json()["plan"]
        session = Session(client, args.plan)
        try:
            for k in np.linspace(0, len(nodes["t"]) - 2, args.updates).astype(int):
                started = time.perf_counter()
                report = session.update(nodes["t"][k], nodes["q"][k], nodes["dq"][k])
                trip = 1e3 * (time.perf_counter() - started)
                print(f"t = {nodes['t'][k]:.3f} s  {report['status']}  violation "
                      f"{report['violation']}  round trip {trip:.1f} ms")
        finally:
            session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
