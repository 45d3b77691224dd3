"""Write the app's OpenAPI document: `python -m app.openapi_export openapi/openapi.json`.

Keys are sorted and the indentation fixed, so the file changes only when the API does.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from app.main import app


def render() -> str:
    """The OpenAPI document as stable JSON text."""
    return json.dumps(app.openapi(), indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m app.openapi_export PATH", file=sys.stderr)
        return 2
    path = Path(argv[0])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render(), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
