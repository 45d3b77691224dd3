"""Optimal-control planning of feed-forward torques: transcription, NLP, Ipopt, verification."""

from planner.ocp.planner import plan
from planner.ocp.result import Plan, Progress

__all__ = ["Plan", "Progress", "plan"]
