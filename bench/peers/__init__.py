"""Peers of the planner measured on the same tasks: a plain CasADi Opti script (`opti`)."""
