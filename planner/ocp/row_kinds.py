"""What each constraint row of an NLP is: its stages' rows, stage after stage, then the
terminal's, each of a kind of `planner.ocp.stage_function.ROW_KINDS`, "dynamics" or
"continuity", then the rows that keep the globals' copies equal ("continuity" too)."""

from __future__ import annotations

import numpy as np

from planner.ocp.problem import Problem, stages


def row_kinds(problem: Problem) -> tuple[np.ndarray, int]:
    """The kind of every row of the problem (lbg.size,) and the number of rows of one
    stage; "constraint" throughout (and 0 rows a stage) where the stages' kinds are not
    known."""
    parts = stages(problem.key.stage_key(), problem.compiled)
    (stage, terminal), (stage_kinds, terminal_kinds) = parts.bounds, parts.kinds
    counts = [c for _, _, c in stage], [c for _, _, c in terminal]
    per_stage = np.repeat(np.array(stage_kinds or ["constraint"] * len(stage), object),
                          counts[0])
    final = np.repeat(np.array(terminal_kinds or ["constraint"] * len(terminal), object),
                      counts[1])
    kinds = np.concatenate([np.tile(per_stage, problem.key.intervals), final,
                            np.full(problem.layout.copy_rows, "continuity", object)])
    if kinds.size != problem.lbg.size:
        return np.full(problem.lbg.size, "constraint", object), 0
    return kinds, int(per_stage.size)
