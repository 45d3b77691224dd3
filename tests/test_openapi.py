"""The committed OpenAPI document is the app's, and documents errors as problems."""

from __future__ import annotations

import json
from pathlib import Path

from app.main import app
from app.openapi_export import render

COMMITTED = Path(__file__).resolve().parents[1] / "openapi" / "openapi.json"


def test_the_committed_document_matches_the_app():
    assert json.loads(COMMITTED.read_text()) == app.openapi(), (
        "openapi/openapi.json is stale: run `make openapi` and commit it")


def test_the_export_is_byte_stable():
    assert render() == render() == COMMITTED.read_text()


def test_every_error_response_is_a_problem():
    doc = app.openapi()
    assert "HTTPValidationError" not in doc["components"]["schemas"]
    for path, operations in doc["paths"].items():
        for method, operation in operations.items():
            for status, response in operation["responses"].items():
                if int(status) >= 400:
                    assert list(response["content"]) == ["application/problem+json"], (
                        method, path, status)
            if path != "/healthz":
                assert "401" in operation["responses"], (method, path)


def test_every_operation_documents_the_431_of_an_over_long_head():
    """The server answers any request whose head (request line, query, header fields)
    exceeds 16 KiB with a 431 problem before routing it (app/server.py): a long query
    string of GET /v1/plans/{job_id}/sample gets one as well as any other operation."""
    for path, operations in app.openapi()["paths"].items():
        for method, operation in operations.items():
            response = operation["responses"].get("431")
            assert response is not None, (method, path)
            assert list(response["content"]) == ["application/problem+json"], (method, path)


def test_the_export_command_writes_the_document(tmp_path):
    from app.openapi_export import main

    target = tmp_path / "sub" / "openapi.json"
    assert main([str(target)]) == 0
    assert target.read_text() == render()
    assert main([]) == 2
