"""The OpenAPI document: valid (openapi-spec-validator), its operations named after their
route functions, no two schemas of one title (a client generated from it, e.g. by
openapi-python-client, names its functions and classes from them)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from openapi_spec_validator import validate

from app.service.config import Settings
from app.service.main import create_app


def document() -> dict[str, Any]:
    app = create_app(Settings(viewer_enabled=False, data_dir=Path("/nonexistent")))
    schema: dict[str, Any] = app.openapi()
    return schema


def test_the_document_is_valid_openapi() -> None:
    schema = document()
    assert schema["openapi"].startswith("3.")
    validate(schema)  # raises, naming the part that is not


def test_operations_are_named_after_their_route_functions() -> None:
    named = {
        (method.upper(), path): op["operationId"]
        for path, ops in document()["paths"].items()
        for method, op in ops.items()
    }
    assert named[("POST", "/domains/{name}/sessions")] == "create_session"
    assert named[("PUT", "/domains/{name}")] == "put_domain"
    assert named[("POST", "/sessions/{session_id}/events")] == "post_events"
    assert named[("GET", "/domains/{name}/prior")] == "read_prior"
    ids = list(named.values())
    assert len(ids) == len(set(ids))
    assert all(i.isidentifier() and i.islower() for i in ids), ids


def test_no_two_schemas_have_one_title() -> None:
    schemas = document()["components"]["schemas"]
    titles = Counter(s.get("title", name) for name, s in schemas.items())
    assert [t for t, n in titles.items() if n > 1] == []
    # validation errors (422) are answered as every other error, and documented so
    assert "HTTPValidationError" not in schemas
    responses = document()["paths"]["/domains/{name}/sessions"]["post"]["responses"]
    assert responses["422"]["content"]["application/json"]["schema"] == {
        "$ref": "#/components/schemas/ErrorPublic"
    }
