"""Each API call as data (method, path, body, auth), shared by the sync and async clients."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import quote, urlencode, urlsplit, urlunsplit

from advisor_client.protocol import unpack
from advisor_client.types import Cell, Decision, EventLike


class AdvisorError(Exception):
    """The service refused a request: ``status`` (HTTP, or 4xxx websocket close code mapped to
    4xx) and its ``detail``; or it could not be reached (:class:`AdvisorUnreachable`)."""

    def __init__(self, status: int, detail: str):
        super().__init__(f"{status}: {detail}")
        self.status = status
        self.detail = detail


class AdvisorUnreachable(AdvisorError):
    """No answer from the service (connection refused, a timeout, the connection dropped):
    ``status`` 0, ``url`` what was called, ``detail`` what went wrong and a hint."""

    def __init__(self, url: str, problem: str, attempts: int = 1):
        tried = f" ({attempts} attempts)" if attempts > 1 else ""
        detail = (
            f"cannot reach the advisor at {url}{tried}: {problem}. Is the service running "
            "there (`advisor serve`, or `python -m app serve`) and is the URL right?"
        )
        super().__init__(0, detail)
        self.url = url


@dataclass
class Session:
    """A live session: its id, its token (needed by every session call) and first decision.

    ``steps``: the steps the service has answered for it so far. The client numbers the events
    it sends with the steps that follow (``"step"``), so that a call that got no answer can be
    sent again: the service answers the steps it applied already instead of applying them
    twice. Use one :class:`Session` object per session, from one thread or task at a time."""

    session_id: str
    token: str
    domain: str
    kappa: float
    window: int
    decision: Decision
    prior_table: str = "*"
    steps: int = 0

    @classmethod
    def of(cls, body: dict[str, Any]) -> Session:
        return cls(
            body["session_id"], body["token"], body["domain"], body["kappa"], body["window"],
            body["decision"], body.get("prior_table", "*"), body["decision"].get("step", 0),
        )  # fmt: skip

    def answered(self, answer: Any) -> None:
        """Count the steps of an answer to events (one decision, a list, or a binary frame)."""
        if isinstance(answer, dict):
            self.steps = int(answer["step"])
        elif isinstance(answer, list):
            if answer:
                self.steps = int(answer[-1]["step"])
        elif len(answer):  # a DecisionFrame: its steps column
            self.steps = int(answer.step[-1])

    @property
    def auth(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"}


@dataclass(frozen=True)
class Call:
    """One API call. ``idempotent``: sending it twice does what sending it once does (GET,
    PUT, DELETE), so it is retried after any failure to get an answer; other calls are retried
    only when the connection could not be made (nothing was sent). Events are idempotent: they
    carry their ``step``, and the service answers a step it has applied again."""

    method: str
    path: str
    json: Any = None
    params: dict[str, Any] = field(default_factory=dict)
    #: a body that is not JSON (its Content-Type in ``headers``): a map file's text
    content: bytes | None = None
    headers: dict[str, str] = field(default_factory=dict)
    admin: bool = False
    idempotent: bool = False
    #: send the client's key if it has one (the answer then shows more: /overview's sessions)
    key_if_any: bool = False

    def __post_init__(self) -> None:
        if self.method in ("GET", "HEAD", "PUT", "DELETE"):
            object.__setattr__(self, "idempotent", True)


def _name(name: str) -> str:
    return quote(name, safe="")


def health() -> Call:
    return Call("GET", "/health")


def domains() -> Call:
    return Call("GET", "/domains")


def domain(name: str) -> Call:
    return Call("GET", f"/domains/{_name(name)}")


def put_domain(
    name: str,
    rows: Sequence[str],
    alpha0: float = 1.0,
    *,
    resolution: float | None = None,
    origin: Sequence[float] | None = None,
    experts: Mapping[str, Any] | None = None,
    destinations: Mapping[tuple[int, int], str] | None = None,
) -> Call:
    """``destinations``: the names of destinations, ``{(row, col): name}`` (cells of goals)."""
    body: dict[str, Any] = {"map": list(rows), "alpha0": alpha0}
    if resolution is not None:
        body["resolution"] = resolution
    if origin is not None:
        body["origin"] = [float(v) for v in origin]
    if destinations is not None:
        body["destinations"] = [
            {"cell": [int(r), int(c)], "name": name} for (r, c), name in destinations.items()
        ]
    if experts is not None:
        body["experts"] = dict(experts)
    return Call("PUT", f"/domains/{_name(name)}", body, admin=True)


def put_domain_file(
    name: str,
    text: str | bytes,
    alpha0: float | None = None,
    *,
    experts: str | Mapping[str, Any] | None = None,
) -> Call:
    """PUT a map file as it is (``text/plain``): its header lines (``resolution:``,
    ``origin:``, ``destination:``) and rows as ``maze import`` or ``maze generate`` wrote
    them. ``experts``: ``"start"`` or ``"anywhere"``, or ``{"source", "per_goal", "seed"}`` as
    the JSON body has it; the service refuses a bad file naming its line and column."""
    params: dict[str, Any] = {}
    if alpha0 is not None:
        params["alpha0"] = alpha0
    if experts is not None:
        given = {"source": experts} if isinstance(experts, str) else dict(experts)
        params["experts"] = given.get("source", "start")
        params |= {k: given[k] for k in ("per_goal", "seed") if k in given}
    body = text.encode("utf-8") if isinstance(text, str) else bytes(text)
    headers = {"Content-Type": "text/plain; charset=utf-8"}
    return Call("PUT", f"/domains/{_name(name)}", params=params, headers=headers,
                content=body, admin=True)  # fmt: skip


def delete_domain(name: str) -> Call:
    return Call("DELETE", f"/domains/{_name(name)}", admin=True)


def add_trajectories(name: str, trajectories: Sequence[EventLike]) -> Call:
    body = {"trajectories": list(trajectories)}
    return Call("POST", f"/domains/{_name(name)}/trajectories", body, admin=True)


def prior(name: str, agent_type: str | None = None) -> Call:
    params = {"agent_type": agent_type} if agent_type else {}
    return Call("GET", f"/domains/{_name(name)}/prior", params=params)


def create_session(
    name: str,
    kappa: float | None = None,
    window: int | None = None,
    agent_type: str | None = None,
    start: Cell | None = None,
    strategy: str | None = None,
    params: Mapping[str, float | int] | None = None,
    budget: Mapping[str, int] | None = None,
) -> Call:
    body: dict[str, Any] = {"kappa": kappa, "window": window, "agent_type": agent_type}
    body |= {"strategy": strategy, "params": dict(params) if params is not None else None}
    body["budget"] = dict(budget) if budget is not None else None
    if start is not None:
        body["start"] = [int(x) for x in start]
    clean = {k: v for k, v in body.items() if v is not None}
    return Call("POST", f"/domains/{_name(name)}/sessions", clean)


def numbered(session: Session, batch: EventLike | Sequence[EventLike]) -> Any:
    """The events as JSON, each with its ``step`` (the steps after ``session.steps``, unless
    the caller numbered them)."""
    if isinstance(batch, Mapping):
        return {"step": session.steps + 1} | dict(batch)
    return [{"step": session.steps + 1 + i} | dict(e) for i, e in enumerate(batch)]


def events(session: Session, batch: EventLike | Sequence[EventLike]) -> Call:
    """Events with their steps: sending them twice applies them once (idempotent)."""
    body = numbered(session, batch)
    return Call(
        "POST", f"/sessions/{session.session_id}/events", body, headers=session.auth,
        idempotent=True,
    )  # fmt: skip


def positions(session: Session, points: Sequence[Sequence[float]]) -> Call:
    body = {"positions": [[float(p[0]), float(p[1])] for p in points]}
    return Call("POST", f"/sessions/{session.session_id}/positions", body, headers=session.auth)


def read_session(session: Session) -> Call:
    return Call("GET", f"/sessions/{session.session_id}", headers=session.auth)


def mute(session: Session, muted: bool = True) -> Call:
    """No more advice for this session (``muted``), or advice again."""
    return Call(
        "POST", f"/sessions/{session.session_id}/mute", {"muted": muted}, headers=session.auth
    )


def end_session(session: Session) -> Call:
    return Call("DELETE", f"/sessions/{session.session_id}", headers=session.auth)


def sessions(limit: int = 100) -> Call:
    return Call("GET", "/sessions", params={"limit": limit}, admin=True)


def overview(limit: int = 100) -> Call:
    """Figures per domain; the live sessions too with the admin or the operator key."""
    return Call("GET", "/overview", params={"limit": limit}, key_if_any=True)


def stream_url(base_url: str, session: Session, binary: bool = False) -> str:
    """``ws(s)://.../sessions/{id}/stream`` for an ``http(s)://`` base URL (with
    ``?format=binary`` for binary answers, :mod:`advisor_client.protocol`). The token goes in a
    header (:func:`stream_headers`), not in the URL, which proxies and servers log."""
    parts = urlsplit(base_url)
    scheme = "wss" if parts.scheme == "https" else "ws"
    path = parts.path.rstrip("/") + f"/sessions/{session.session_id}/stream"
    query = {"format": "binary"} if binary else {}
    return urlunsplit((scheme, parts.netloc, path, urlencode(query), ""))


def stream_headers(session: Session) -> dict[str, str]:
    """The websocket's credentials: the session token as a bearer token."""
    return session.auth


def result(status: int, body: Any, text: str) -> Any:
    """The answer's body, or :class:`AdvisorError` with the service's detail."""
    if status >= 400:
        detail = body.get("detail") if isinstance(body, dict) else None
        raise AdvisorError(status, str(detail) if detail is not None else text[:500])
    return body


def frame_answer(message: str | bytes) -> Any:
    """A websocket answer frame: a binary frame's decisions (a :class:`DecisionFrame`), a
    JSON frame's decisions, or :class:`AdvisorError` for an error frame (always JSON)."""
    if isinstance(message, bytes):
        return unpack(message)
    return frame_result(json.loads(message))


def frame_result(body: Any) -> Any:
    """A websocket answer: decisions, or :class:`AdvisorError` for an error frame."""
    if isinstance(body, dict) and "detail" in body:
        raise AdvisorError(int(body.get("status", 422)), str(body["detail"]))
    return body
