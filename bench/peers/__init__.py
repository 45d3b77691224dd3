"""Peers of the planner measured on the same tasks: a plain CasADi Opti script (`opti`),
rockit (`rockit`) and opty (`opty`, run by the interpreter of its own virtualenv)."""
