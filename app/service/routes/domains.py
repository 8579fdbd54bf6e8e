from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool

from app.service import answers, ops
from app.service.deps import AdminDep, DomainDep, DomainName, StateDep
from app.service.mapbody import text_of
from app.service.openapi import body, domain_body
from app.service.problems import BadInput
from app.service.schemas import (
    ALPHA0_MAX,
    ALPHA0_MIN,
    AgentType,
    DomainPublic,
    DomainPut,
    ErrorPublic,
    PriorPublic,
    TrajectoriesAccepted,
)

router = APIRouter(tags=["domains"])
JSON = "application/json"
NOT_FOUND: dict[int | str, dict[str, Any]] = {404: {"model": ErrorPublic}}
ADMIN: dict[int | str, dict[str, Any]] = {401: {"model": ErrorPublic}, 403: {"model": ErrorPublic}}
INVALID: dict[int | str, dict[str, Any]] = {422: {"model": ErrorPublic}}
BODY: dict[int | str, dict[str, Any]] = {  # unreadable, oversize or not JSON bodies
    400: {"model": ErrorPublic}, 413: {"model": ErrorPublic}, 415: {"model": ErrorPublic},
}  # fmt: skip


@router.get("/domains", response_model=list[DomainPublic])
async def list_domains(state: StateDep) -> Response:
    """Every domain: its map, start, goals and prior size (each made once per version, in a
    worker thread)."""
    await state.sessions.sync_catalog()
    return Response(await answers.domains(state.catalog.states()), media_type=JSON)


@router.get("/domains/{name}", response_model=DomainPublic, responses=NOT_FOUND | INVALID)
async def read_domain(domain: DomainDep) -> Response:
    return Response(await answers.domain(domain), media_type=JSON)


@router.put(
    "/domains/{name}",
    dependencies=[AdminDep],
    response_model=DomainPublic,
    openapi_extra=domain_body(),
    responses={201: {"model": DomainPublic, "description": "Created"}} | ADMIN | INVALID | BODY,
)
async def put_domain(
    name: DomainName,
    request: Request,
    state: StateDep,
    alpha0: Annotated[
        float | None,
        Query(
            ge=ALPHA0_MIN,
            le=ALPHA0_MAX,
            allow_inf_nan=False,
            description="With a text/plain body: the Dirichlet hyperprior alpha0 (default 1).",
        ),
    ] = None,
    experts: Annotated[
        Literal["start", "anywhere"] | None,
        Query(
            description="With a text/plain body: learn the prior from simulated experts "
            "starting there (as the JSON body's experts.source)."
        ),
    ] = None,
    per_goal: Annotated[
        int | None,
        Query(ge=1, le=1000, description="With experts: walks per goal (default 10)."),
    ] = None,
    seed: Annotated[
        int | None,
        Query(ge=0, le=2**32 - 1, description="With experts: the random seed (default 0)."),
    ] = None,
) -> Response:
    """Create (201) or replace (200) a domain. The same map keeps its trajectories and its
    live sessions; a new map starts with an empty prior and ends the old map's sessions.

    The body is JSON (`DomainPut`: the map as rows, or as the map file's `text`), or the map
    file as it is with `Content-Type: text/plain` (its header lines give the resolution and
    origin; alpha0 and the simulated experts then come as query parameters). A bad map is
    refused (422) naming the line and column, as `maze check` does."""
    raw = await request.body()
    query = {"alpha0": alpha0, "experts": experts, "per_goal": per_goal, "seed": seed}
    if is_text(request.headers.get("content-type")):
        body = text_body(text_of(raw), query)
    else:
        body = json_body(raw, query)
    await state.sessions.sync_domain(name)
    replaced = [state.catalog.find(name)]  # the state this PUT replaces: freed off the loop
    domain, created, kept = await run_in_threadpool(ops.put_domain, state, name, body)
    await ops.after_put(state, domain, created, kept)
    await ops.let_go(replaced)
    return Response(await answers.domain(domain), 201 if created else 200, media_type=JSON)


def is_text(kind: str | None) -> bool:
    return kind is not None and kind.split(";", 1)[0].strip().lower() == "text/plain"


def text_body(text: str, query: dict[str, Any]) -> DomainPut:
    """A text/plain PUT: the map file's text, its options from the query."""
    if text.lstrip().startswith("{"):
        raise BadInput(
            "this text/plain body is JSON: send it with Content-Type: application/json "
            "(text/plain is for the map file as it is)"
        )
    if query["experts"] is None and (query["per_goal"], query["seed"]) != (None, None):
        raise BadInput("per_goal and seed go with experts (start or anywhere)")
    fields: dict[str, Any] = {"text": text}
    if query["alpha0"] is not None:
        fields["alpha0"] = query["alpha0"]
    if query["experts"] is not None:
        given = {"per_goal": query["per_goal"], "seed": query["seed"]}
        experts = {"source": query["experts"]} | {k: v for k, v in given.items() if v is not None}
        fields["experts"] = experts
    try:
        return DomainPut.model_validate(fields)
    except ValidationError as exc:
        errors = exc.errors(include_url=False, include_context=False, include_input=False)
        raise RequestValidationError([{**e, "loc": ("query", *e["loc"])} for e in errors]) from None


def json_body(raw: bytes, query: dict[str, Any]) -> DomainPut:
    """A JSON PUT (or one without a Content-Type), validated as FastAPI would (422, the
    problems listed under ``errors``)."""
    given = [k for k, v in query.items() if v is not None]
    if given:
        raise BadInput(
            f"{', '.join(given)}: query parameters only go with a text/plain body (the map "
            "file as it is); a JSON body carries them itself"
        )
    if not raw.strip():
        raise BadInput(
            'no body: send the domain as JSON, {"map": [rows]} or {"text": "the map '
            'file"}, or the map file as it is with Content-Type: text/plain'
        )
    try:
        return DomainPut.model_validate_json(raw)
    except ValidationError as exc:
        errors = exc.errors(include_url=False, include_context=False, include_input=False)
        if raw.lstrip()[:1] not in (b"{", b"[") and errors[0]["type"] == "json_invalid":
            raise BadInput(
                "the body is not JSON: a map file goes as it is with Content-Type: "
                "text/plain (curl --data-binary @MAP.txt -H 'Content-Type: text/plain')"
            ) from None
        raise RequestValidationError([{**e, "loc": ("body", *e["loc"])} for e in errors]) from None


@router.delete(
    "/domains/{name}", dependencies=[AdminDep], status_code=204, responses=NOT_FOUND | ADMIN
)
async def delete_domain(name: DomainName, state: StateDep) -> None:
    """Delete a domain with its trajectories and counts; its live sessions end."""
    domain = await state.sessions.domain(name)
    await run_in_threadpool(state.catalog.delete, name)
    await ops.after_delete(state, name, domain.version)
    gone = [domain]
    del domain
    await ops.let_go(gone)


@router.post(
    "/domains/{name}/trajectories",
    dependencies=[AdminDep],
    status_code=201,
    openapi_extra=body("TrajectoriesCreate"),
    responses=NOT_FOUND | ADMIN | INVALID | BODY | {409: {"model": ErrorPublic}},
)
async def add_trajectories(
    request: Request, domain: DomainDep, state: StateDep
) -> TrajectoriesAccepted:
    """Store expert trajectories durably (before answering) and update the prior at once;
    live sessions of the domain are advised from the new prior from their next event. If the
    domain is PUT again with the same map meanwhile, they go to it; if its map is replaced by
    another, nothing is stored and the answer is 409."""
    accepted, went = await run_in_threadpool(ops.ingest, state, domain, await request.body())
    await state.sessions.retable(went)
    return accepted


@router.get("/domains/{name}/prior", response_model=PriorPublic, responses=NOT_FOUND | INVALID)
async def read_prior(
    domain: DomainDep,
    agent_type: Annotated[AgentType | None, Query(description="Omit for the pooled prior.")] = None,
) -> Response:
    """theta_s(a) for every cell (null for walls). An agent type without data of its own is
    served the pooled prior, as its sessions are; ``table`` says which one answered. Made
    once per prior version, in a worker thread."""
    return Response(await answers.prior(domain, agent_type), media_type=JSON)
