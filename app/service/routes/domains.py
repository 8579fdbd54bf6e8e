from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response
from starlette.concurrency import run_in_threadpool

from app.service import answers, ops
from app.service.deps import AdminDep, DomainDep, DomainName, StateDep
from app.service.openapi import body
from app.service.schemas import (
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
    responses={201: {"model": DomainPublic, "description": "Created"}} | ADMIN | INVALID | BODY,
)
async def put_domain(name: DomainName, body: DomainPut, state: StateDep) -> Response:
    """Create (201) or replace (200) a domain. The same map keeps its trajectories and its
    live sessions; a new map starts with an empty prior and ends the old map's sessions."""
    await state.sessions.sync_domain(name)
    replaced = [state.catalog.find(name)]  # the state this PUT replaces: freed off the loop
    domain, created, kept = await run_in_threadpool(ops.put_domain, state, name, body)
    await ops.after_put(state, domain, created, kept)
    await ops.let_go(replaced)
    return Response(await answers.domain(domain), 201 if created else 200, media_type=JSON)


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
