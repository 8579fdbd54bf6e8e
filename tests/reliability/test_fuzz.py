"""Schemathesis against the service's own OpenAPI document, over real HTTP (uvicorn).

Every documented operation is fuzzed in schemathesis' three pytest phases (the schema's
examples, its boundary "coverage" cases, random fuzzing), positive and negative data, with all
of its response checks: no 5xx, every status documented, every body matching its schema,
invalid data refused, auth not ignored, 405s naming the allowed methods.

To get past the front door, cases are given credentials the way a client would: the admin key
on admin routes, and on session routes, three cases in four, a live session's id and token (a
fresh session each time, since a case may end it); three in four domain-scoped reads and
writes are pointed at ``default``. The rest keep their generated ids and names (unknown: 404).

Schema-valid input can still be refused for what no schema can say (a wall cell, a jump
between cells, a map without a goal): the built-in "positive data accepted" check is replaced
by :func:`check_refusal_is_semantic`, which allows such a 422 only when its detail names one of
those reasons, so a validator stricter than the schema still fails the test.

Generated cases and HTTP requests (cases plus the probes some checks send) are counted per
operation; ``test_every_operation_was_fuzzed`` asserts at least ``MIN_CASES`` generated
cases, every operation reached, and no unhandled exception in the server's log.
"""

from __future__ import annotations

import zlib
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import requests
import requests.adapters
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.core.parameters import ParameterLocation
from schemathesis.core.transport import Response
from schemathesis.generation.meta import CoveragePhaseData, CoverageScenario
from schemathesis.specs.openapi.checks import ignored_auth

from app.domain.maps import DEFAULT_MAP
from app.service.config import Settings
from app.service.main import create_app
from app.service.schemas import ACTION_RULE
from tests.reliability.conftest import Live, server_errors

MIN_CASES = 1000
EXAMPLES_PER_OPERATION = 50
#: Why a schema-valid request may still get a 422: the parts of the contract no schema states.
SEMANTIC = (
    "is a wall", "is off the", "map:", "is not where the previous step leads",
    "is not one move from", "ambiguous", "give an action", "larger than this service allows",
    "does not read",  # a parameter of another strategy (the schema lists every strategy's)
    "has no resolution",  # positions in metres to a domain placed in cells only
    "a jump this far is refused",  # a reading more than max_jump moves from the last
    "experts:",  # more simulated experts than the service learns from
    "origin needs resolution",  # a rule between two fields
    # PUT /domains/{name}: the map as rows or as a file's text, one of them; a file's header
    # gives the metres; query options go with a text/plain body, per_goal and seed with experts
    "one of them", "header lines", "only go with a text/plain body", "go with experts",
    "this text/plain body is JSON",
    # a cell has 2 coordinates on one floor and 3 on several, U and D ride only on several;
    # one schema serves both kinds of map, the map says which ("this map has one floor: ...")
    "this map has",
)  # fmt: skip
#: JSON Schema's "integer" admits 1.0; the service takes only 1 (on purpose: a float is not a
#: cell or a move, see schemas.py). Refusals that say so are allowed when the body has one.
STRICT_INT = ("Input should be a valid integer", ACTION_RULE)
DEFAULT_MAP_ROWS = DEFAULT_MAP.read_text().split()

#: The document the service serves (``test_served_schema_is_the_fuzzed_one`` checks it).
SCHEMA: dict[str, Any] = create_app(
    Settings(viewer_enabled=False, data_dir=Path("/nonexistent"))
).openapi()
CONFIG = schemathesis.Config.from_dict(
    {
        "seed": 20140601,
        "generation": {"max-examples": EXAMPLES_PER_OPERATION, "database": "none"},
        "checks": {"positive_data_acceptance": {"enabled": False}},
    }
)
schema = schemathesis.openapi.from_dict(SCHEMA, config=CONFIG)
#: After a successful DELETE the session is gone, so the "ignored auth" probe that follows
#: (same id, a forged token) is rightly told 404, which that check counts as a failure. The
#: access matrix (test_access.py) checks this route's 401/403s on a live session instead.
EXCLUDED = {"DELETE /sessions/{session_id}": [ignored_auth]}
OPERATIONS = {f"{m.upper()} {p}" for p, ops in SCHEMA["paths"].items() for m in ops}


class Target:
    """The live server, what was sent to it, and helpers that set cases up (over httpx, so
    that only schemathesis' own traffic, through ``requests``, is counted)."""

    def __init__(self, live: Live):
        self.live = live
        self.http = requests.Session()
        self.http.trust_env = False  # no proxy lookups: loopback only
        self.setup = httpx.Client(base_url=live.url, timeout=10)
        self.cases: Counter[str] = Counter()
        self.requests: Counter[str] = Counter()
        self.sent = 0  # every HTTP request schemathesis made: cases, and its checks' probes

    def new_session(self) -> tuple[str, str]:
        r = self.setup.post("/domains/default/sessions", json={})
        if r.status_code == 404:  # a case deleted `default`
            self.restore_default()
            r = self.setup.post("/domains/default/sessions", json={})
        assert r.status_code == 201, r.text
        body = r.json()
        return body["session_id"], body["token"]

    def restore_default(self) -> None:
        r = self.setup.put(
            "/domains/default", json={"map": DEFAULT_MAP_ROWS}, headers=self.live.admin
        )
        assert r.status_code in (200, 201), r.text


@pytest.fixture(scope="module")
def target(live: Live) -> Iterator[Target]:
    t = Target(live)
    send = requests.adapters.HTTPAdapter.send

    def counted(adapter: requests.adapters.HTTPAdapter, *args: Any, **kwargs: Any) -> Any:
        t.sent += 1
        return send(adapter, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(requests.adapters.HTTPAdapter, "send", counted)
        yield t
    t.http.close()
    t.setup.close()


def _pick(value: object, k: int = 4) -> bool:
    """Three cases in four, chosen by the generated value (so reruns choose the same)."""
    return zlib.crc32(repr(value).encode()) % k != 0


def _withheld(case: schemathesis.Case[Any]) -> set[str]:
    """Headers the case leaves out on purpose (a coverage case "missing header X")."""
    data = case.meta.phase.data if case.meta is not None else None
    if isinstance(data, CoveragePhaseData) and data.scenario == CoverageScenario.MISSING_PARAMETER:
        return {(data.parameter or "").lower()}
    return set()


def prepare(case: schemathesis.Case[Any], target: Target) -> dict[str, str]:
    """Live ids in the case, and the credentials to send with it (passed to the call, so
    schemathesis knows them for explicit auth and probes the route without them and with
    invalid ones): see the module docstring."""
    op = case.operation
    method, path = op.method.upper(), op.path
    schemes = {name for sec in op.definition.raw.get("security", []) for name in sec}
    meta = case.meta
    # a case whose path or credential header is the invalid part keeps what it generated
    bad_path = meta is not None and meta.is_negative_at(ParameterLocation.PATH)
    bad_header = meta is not None and meta.is_negative_at(ParameterLocation.HEADER)
    params = case.path_parameters if not bad_path else None
    withheld = _withheld(case)
    credentials = {}
    if schemes == {"APIKeyHeader"} and not bad_header and "x-api-key" not in withheld:
        credentials["X-API-Key"] = target.live.admin_key
    if "{session_id}" in path and params is not None and _pick(params.get("session_id")):
        sid, token = target.new_session()
        params["session_id"] = sid
        if not bad_header and "authorization" not in withheld:
            credentials["Authorization"] = f"Bearer {token}"
    if "{name}" in path and params is not None and method != "PUT" and _pick(params.get("name")):
        params["name"] = "default"
    return credentials


def check_refusal_is_semantic(case: schemathesis.Case[Any], response: Response) -> None:
    """Schema-valid data: accepted, or refused for a reason the schema cannot express."""
    meta = case.meta
    if meta is None or meta.generation.mode != schemathesis.GenerationMode.POSITIVE:
        return
    if response.status_code == 422:
        detail = response.json()["detail"]
        strict = any(r in detail for r in STRICT_INT) and _has_integral_float(case.body)
        assert strict or any(reason in detail for reason in SEMANTIC), (
            f"{case.operation.label}: schema-valid input refused: {detail}"
        )


def _has_integral_float(value: object) -> bool:
    if isinstance(value, float):
        return value.is_integer()
    if isinstance(value, dict):
        return any(_has_integral_float(v) for v in value.values())
    if isinstance(value, list):
        return any(_has_integral_float(v) for v in value)
    return False


@schema.parametrize()
@settings(suppress_health_check=list(HealthCheck), deadline=None)
def test_fuzz_every_operation(case: schemathesis.Case[Any], target: Target) -> None:
    credentials = prepare(case, target)
    before = target.sent
    try:
        response = case.call_and_validate(
            base_url=target.live.url,
            session=target.http,
            headers=credentials,
            excluded_checks=EXCLUDED.get(case.operation.label, []),
        )
        check_refusal_is_semantic(case, response)
    finally:
        label = case.operation.label
        target.cases[label] += 1
        target.requests[label] += target.sent - before
        name = (case.path_parameters or {}).get("name")
        if case.method.upper() in ("PUT", "DELETE") and name == "default":
            target.restore_default()  # keep the domain the other cases point at


def test_every_operation_was_fuzzed(target: Target) -> None:
    """Runs after the fuzzing above (same module, file order): its totals."""
    assert set(target.cases) == OPERATIONS, OPERATIONS - set(target.cases)
    total = sum(target.requests.values())
    print(f"\nschemathesis: {sum(target.cases.values())} cases, {total} requests")
    for label in sorted(target.requests):
        print(f"  {label}: {target.cases[label]} cases, {target.requests[label]} requests")
    assert sum(target.cases.values()) >= MIN_CASES
    assert server_errors(target.live) == []


def test_served_schema_is_the_fuzzed_one(live: Live) -> None:
    served = requests.get(f"{live.url}/openapi.json", timeout=10).json()
    assert served == SCHEMA
