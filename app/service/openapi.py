"""OpenAPI for bodies the routes parse themselves (for speed, or off the event loop).

The events and trajectories routes read the raw bytes and validate them with pydantic-core in
one call; FastAPI does not see their body type, so it is declared here: ``body(name)`` for the
route's ``openapi_extra`` and :func:`install_openapi` to add the schemas to the components.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import APIRoute
from pydantic import TypeAdapter

from app.service.config import Settings
from app.service.schemas import DomainPut, ErrorPublic, EventIn, TrajectoriesCreate

REF = "#/components/schemas/{model}"
BODIES: dict[str, TypeAdapter[Any]] = {
    "Events": TypeAdapter(EventIn | list[EventIn]),
    "TrajectoriesCreate": TypeAdapter(TrajectoriesCreate),
    "DomainPut": TypeAdapter(DomainPut),
}
EXAMPLES: dict[str, Any] = {
    "Events": [{"state": [28, 0], "action": "E"}, {"state": [28, 1], "next_state": [27, 1]}],
    "TrajectoriesCreate": {
        "trajectories": [{"agent_type": "visitor", "steps": [{"state": [28, 0], "action": "E"}]}]
    },
    "DomainPut": {"map": ["#######", "#G..#G#", "#.#.#.#", "#S....#", "#######"]},
}
#: a map file as ``maze import`` writes it (a text/plain PUT /domains/{name})
MAP_FILE = "resolution: 0.5\norigin: -12.0 4.5 0.0\n#######\n#G..#G#\n#.#.#.#\n#S....#\n#######\n"


def body(name: str) -> dict[str, Any]:
    """``openapi_extra`` declaring a JSON request body of schema ``name``."""
    schema = {"$ref": REF.format(model=name)}
    content = {"application/json": {"schema": schema, "example": EXAMPLES[name]}}
    return {"requestBody": {"required": True, "content": content}}


def domain_body() -> dict[str, Any]:
    """``openapi_extra`` of PUT /domains/{name}: JSON (``DomainPut``) or the map file as
    text/plain."""
    extra = body("DomainPut")
    extra["requestBody"]["content"]["text/plain"] = {
        "schema": {"type": "string", "description": "The map file as it is (header lines, rows)."},
        "example": MAP_FILE,
    }
    return extra


def install_openapi(app: FastAPI) -> None:
    """The document: FastAPI's, the bodies the routes read themselves, and the limits of this
    service's settings (request bodies at most ``max_body_bytes``: the API's description)."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = get_openapi(
                title=app.title,
                version=app.version,
                description=app.description,
                routes=app.routes,
            )
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            for name, adapter in BODIES.items():
                js = adapter.json_schema(ref_template=REF)
                components.update(js.pop("$defs", {}))
                components[name] = js
            # validation errors are answered as {"detail": "where: what", "errors": [...]}, an
            # ErrorPublic: FastAPI's own schemas of them go, so that no two schemas have one
            # title (a generated client would name two classes alike and drop one)
            components.setdefault("ErrorPublic", ErrorPublic.model_json_schema(ref_template=REF))
            for name in ("HTTPValidationError", "ValidationError"):
                components.pop(name, None)
            schema["paths"] = refer(schema["paths"], "HTTPValidationError", "ErrorPublic")
            state_limits(components, app.state.settings)
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def operation_id(route: APIRoute) -> str:
    """A route's operationId: its function's name (``create_session``, ``put_domain``)."""
    return route.name


def refer(value: Any, old: str, new: str) -> Any:
    """``value`` with every ``$ref`` to the schema ``old`` pointing at ``new`` instead."""
    if isinstance(value, dict):
        if value.get("$ref") == REF.format(model=old):
            return {**value, "$ref": REF.format(model=new)}
        return {k: refer(v, old, new) for k, v in value.items()}
    if isinstance(value, list):
        return [refer(v, old, new) for v in value]
    return value


def state_limits(components: dict[str, Any], settings: Settings) -> None:
    """The limits this service enforces (its settings), in the schemas they bound."""
    window = components["SessionCreate"]["properties"]["window"]
    window["maximum"] = settings.max_window
    window["description"] += (
        f" At most {settings.max_window}; with goal_aware and beta > 0, goals x window at most "
        f"{settings.max_goal_window}."
    )
    for branch in components["Events"]["anyOf"]:
        if branch.get("type") == "array":
            branch["maxItems"] = settings.max_batch_events
    rows = components["DomainPut"]["properties"]["map"]
    rows["description"] += (
        f" At most {settings.max_map_cells} cells (rows x the longest row), and goals x free "
        f"cells at most {settings.max_goal_cells}."
    )
    rows["x-max-cells"] = settings.max_map_cells
    rows["x-max-goal-cells"] = settings.max_goal_cells
    trajectories = components["TrajectoriesCreate"]
    trajectories["description"] = (
        f"At most {settings.max_trajectory_steps} steps in all in one request."
    )
    trajectories["x-max-steps"] = settings.max_trajectory_steps
    positions = components["PositionsIn"]["properties"]["positions"]
    positions["description"] = (
        f"The moves they walk: at most {settings.max_batch_events} in one request; one reading "
        f"at most {settings.max_jump} moves from the one before."
    )
