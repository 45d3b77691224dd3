"""The browser viewer's static files, served at "/", and its palette at "/palette.js".

A plain `Mount("/")` matches every path, and Starlette prefers it to a route that
matches the path but not the method: `GET /v1/dynamics` became the static 404 instead of
a 405. This mount matches only the paths of its own files (and "/"), so every other path
reaches the API's 404 and 405; its files answer GET and HEAD.
"""

from __future__ import annotations

import json
from pathlib import Path

from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import BaseRoute, Match, Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.types import Scope

from planner.plots import PALETTE

DIRECTORY = Path(__file__).parent / "static"


class ViewerMount(Mount):
    """StaticFiles of `directory` at "/", matching only the files it holds."""

    def __init__(self, directory: Path = DIRECTORY):
        super().__init__("/", app=StaticFiles(directory=directory, html=True), name="viewer")
        self.paths = {"/"} | {"/" + p.relative_to(directory).as_posix()
                              for p in directory.rglob("*") if p.is_file()}

    def matches(self, scope: Scope) -> tuple[Match, Scope]:
        if scope["type"] == "http" and scope["path"] not in self.paths:
            return Match.NONE, {}
        match, child = super().matches(scope)
        if match == Match.FULL and scope.get("method") not in ("GET", "HEAD"):
            return Match.PARTIAL, child  # the files' 405
        return match, child


async def _palette(_: Request) -> Response:
    """`window.UNDERTOW_PALETTE`: the figures' colours (`planner.plots.PALETTE`), so that
    the viewer's curves look like the PNG's."""
    return Response(f"window.UNDERTOW_PALETTE = {json.dumps(PALETTE)};\n",
                    media_type="text/javascript")


def routes() -> list[BaseRoute]:
    """The viewer's routes, to append after the API's."""
    return [Route("/palette.js", _palette, methods=["GET"]), ViewerMount()]
