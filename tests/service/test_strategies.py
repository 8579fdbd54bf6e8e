"""Sessions with an advising strategy decide exactly as the core's advisor for that strategy.

The reference is rebuilt independently from what the database holds: the pooled prior from the
stored trajectories (ActionPrior.fit) and, for goal_aware, the per-goal counts from the goal each
stored trajectory ended at (GoalPriors.add). New expert trajectories arrive mid-stream, and live
sessions must follow them (the core reference is given the new tables and goal priors).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import fields
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from advisor_client.protocol import unpack
from fastapi.testclient import TestClient
from hypothesis import given, settings
from hypothesis import strategies as st

from app import strategies
from app.advice import guide as guide_module
from app.advice.guide import GuideMap
from app.advice.params import StrategyParams
from app.advice.priors import GoalPriors
from app.domain.building import Building, Domain
from app.domain.floorplans import generate_floors
from app.domain.grid import ACTIONS
from app.domain.paths import expert_trajectory
from app.service.data.domains import service_leads
from app.service.main import create_app
from app.service.state import ServiceState
from app.strategies import make_advisor, names
from tests.service.conftest import make_settings, open_session
from tests.service.test_decisions_property import core_tables, expected_json

STRATEGIES = names()


#: a building of two floors (a lift bank, two stairwells, named destinations) served as
#: ``tower`` beside the shipped maze, ``default``, with simulated experts' prior
TOWER = generate_floors(20, 20, 2, np.random.default_rng(3), n_goals=3, purpose="hospital")


def put_tower(client: TestClient, admin: dict[str, str], name: str = "tower") -> Building:
    """``TOWER`` put as ``name``, its prior learnt from simulated experts (2 per goal)."""
    body = {"text": TOWER.to_text(), "experts": {"per_goal": 2}}
    r = client.put(f"/domains/{name}", json=body, headers=admin)
    assert r.status_code in (200, 201), r.text
    return TOWER


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, ServiceState]]:
    with TestClient(create_app(make_settings(Path(tmp_path_factory.mktemp("data"))))) as client:
        service: ServiceState = client.app.state.service  # type: ignore[attr-defined]
        put_tower(client, {"X-API-Key": service.admin_key})
        yield client, service


def core_goal_priors(service: ServiceState, name: str = "default") -> GoalPriors:
    state = service.catalog.get(name)
    grid = state.domain
    stored = service.store.trajectories(name)
    index = [grid.goals.index(t.goal) if t.goal in grid.goals else None for t in stored]
    priors = GoalPriors(grid.n_states, grid.goals, state.view.alpha0, grid.n_actions)
    return priors.add([t.pairs for t in stored], index)


def add_expert(
    client: TestClient, service: ServiceState, grid: Domain, rng: np.random.Generator,
    name: str = "default",
) -> None:  # fmt: skip
    """One expert trajectory to a random goal, from a random cell, with its goal stated."""
    goal = grid.goals[int(rng.integers(len(grid.goals)))]
    pairs = expert_trajectory(grid, int(rng.integers(grid.n_states)), goal, rng)
    steps = [{"state": grid.cell(p), "action": grid.actions[q]} for p, q in pairs.tolist()]
    if not steps:
        return
    body = {"trajectories": [{"steps": steps, "goal": grid.cell(goal)}]}
    headers = {"X-API-Key": service.admin_key}
    r = client.post(f"/domains/{name}/trajectories", json=body, headers=headers)
    assert r.status_code == 201, r.text


def moves(grid: Domain, s: int, rng: np.random.Generator) -> list[int]:
    """Up to 80 moves from ``s``: random ones (of every action of the map), or an expert's
    path to a random goal (where the goals' priors disagree, so a goal posterior moves), with
    a few random moves mixed in."""
    n, a_n = int(rng.integers(0, 80)), grid.n_actions
    if rng.random() < 0.5:
        return [int(a) for a in rng.integers(0, a_n, n)]
    goal = grid.goals[int(rng.integers(len(grid.goals)))]
    path = [int(a) for a in expert_trajectory(grid, s, goal, rng)[:, 1].tolist()]
    noise = rng.random(len(path)) < 0.1
    return [int(rng.integers(a_n)) if k else a for a, k in zip(path, noise, strict=True)][:n]


def led(decision: dict[str, Any], core: Any, grid: Domain) -> dict[str, Any]:
    """A decision as one event's answer has it: with the destination guide's advice leads to
    (the core advisor's target) when it advises."""
    target = getattr(core, "target", -1)
    if not decision["advise"] or target < 0:
        return decision
    name = grid.goal_names[target] if grid.goal_names is not None else None
    return decision | {"leads_to": {"goal": target, "cell": list(grid.cell(grid.goals[target])),
                                    "name": name}}  # fmt: skip


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    strategy=st.sampled_from([*STRATEGIES, "goal_aware", "goal_aware", "guide", "guide"]),
    kappa=st.sampled_from([0.0, 0.3, 0.5, 1.0]),
    window=st.sampled_from([1, 7, 60, 300]),
    params=st.fixed_dictionaries(
        {
            "n_steps": st.integers(0, 50),
            "threshold": st.sampled_from([0.0, 0.1, 0.3, 0.6]),
            "rate": st.sampled_from([0.0, 0.2, 1.0]),
            "beta": st.sampled_from([0.0, 0.5, 1.0]),
            "seed": st.integers(0, 1000),
            "p_lost": st.sampled_from([0.001, 0.3, 0.5, 0.9]),
            "slack": st.sampled_from([0.01, 0.5, 1.0]),
            "spread": st.sampled_from([0.0, 0.1, 1.0]),
        }
    ),
    transport=st.sampled_from(["rest", "websocket", "binary"]),
    domain=st.sampled_from(["default", "tower"]),
)
def test_strategy_sessions_decide_as_the_core(
    live: tuple[TestClient, ServiceState],
    seed: int,
    strategy: str,
    kappa: float,
    window: int,
    params: dict[str, Any],
    transport: str,
    domain: str,
) -> None:
    """On the shipped maze and on a building of two floors (cells [floor, row, col], six
    actions, the binary frame's wide form)."""
    client, service = live
    grid = service.catalog.get(domain).domain
    rng = np.random.default_rng(seed)
    start = grid.start if rng.random() < 0.5 else int(rng.integers(grid.n_states))
    given = {name: params[name] for name in strategies.get(strategy).reads}  # its own only
    sid, auth, created = open_session(
        client, domain, kappa=kappa, window=window, start=grid.cell(start), strategy=strategy,
        params=given,
    )  # fmt: skip
    assert created["strategy"] == strategy
    assert created["params"] == given  # exactly the parameters in force
    goal_priors = core_goal_priors(service, domain)
    core = make_advisor(
        strategy, core_tables(service, domain), kappa, window, StrategyParams(**params),
        goal_priors,
        GuideMap.of(grid, goal_priors, leads=service_leads(grid, service.catalog.lead_cells)),
    )  # fmt: skip
    expect = partial(expected_json, service=service, name=domain)
    assert created["decision"] == led(expect(core.start(start)), core, grid)
    token = auth["Authorization"].removeprefix("Bearer ")
    url = f"/sessions/{sid}/stream?token={token}" + ("&format=binary" * (transport == "binary"))
    ws = client.websocket_connect(url) if transport != "rest" else None
    s = start
    with ws or _Nothing():
        for _ in range(int(rng.integers(1, 5))):
            if rng.random() < 0.3:  # new expert data: the session follows it from now on
                add_expert(client, service, grid, rng, domain)
                core.use_tables(core_tables(service, domain), core_goal_priors(service, domain))
            events, expected = [], []
            for a in moves(grid, s, rng):
                s2 = int(grid.next_state[s, a])
                events.append({"state": grid.cell(s), "action": grid.actions[a]})
                expected.append(expect(core.observe(s, a, s2)))
                s = s2
            if ws is not None and transport == "binary":
                ws.send_text(json.dumps(events))
                got = unpack(ws.receive_bytes()).to_dicts()
            elif ws is not None:
                ws.send_text(json.dumps(events))
                got = json.loads(ws.receive_text())
            else:
                r = client.post(f"/sessions/{sid}/events", json=events, headers=auth)
                assert r.status_code == 200, r.text
                got = r.json()
            assert got == expected
    summary = client.get(f"/sessions/{sid}", headers=auth).json()
    assert summary["strategy"] == strategy and summary["steps"] == core.steps
    assert summary["params"] == given
    assert client.delete(f"/sessions/{sid}", headers=auth).status_code == 200


def test_goal_aware_session_rules_out_a_goal_it_walked_past(
    live: tuple[TestClient, ServiceState],
) -> None:
    client, service = live
    grid = service.catalog.get("default").domain
    goal = grid.goals[0]
    step = next(a for a in range(4) if grid.next_state[goal, a] != goal)
    sid, auth, _ = open_session(client, start=grid.cell(goal), strategy="goal_aware")
    before = client.get(f"/sessions/{sid}", headers=auth).json()["goals"]
    assert [g["goal"] for g in before] == [list(grid.cell(g)) for g in grid.goals]
    assert not any(g["ruled_out"] for g in before)
    assert all(math.isclose(g["p"], 1 / len(grid.goals)) for g in before)
    r = client.post(
        f"/sessions/{sid}/events", json={"state": grid.cell(goal), "action": ACTIONS[step]},
        headers=auth,
    )  # fmt: skip
    assert r.status_code == 200, r.text
    after = client.get(f"/sessions/{sid}", headers=auth).json()["goals"]
    assert after[0]["ruled_out"] and after[0]["p"] == 0.0
    assert not any(g["ruled_out"] for g in after[1:])
    assert math.isclose(sum(g["p"] for g in after), 1.0)
    listed = client.get("/overview", headers=operator(client)).json()["sessions"]
    mine = next(x for x in listed if x["session_id"] == sid)
    assert mine["strategy"] == "goal_aware" and mine["goals"] == after


def test_sessions_default_to_the_papers_rule(live: tuple[TestClient, ServiceState]) -> None:
    client, _ = live
    sid, auth, created = open_session(client)
    assert created["strategy"] == "paper"
    assert created["params"] == {}  # the paper's rule reads no parameter besides kappa
    summary = client.get(f"/sessions/{sid}", headers=auth).json()
    assert summary["strategy"] == "paper" and summary["goals"] is None
    assert summary["params"] == {}


def test_a_session_states_the_parameters_in_force_with_their_defaults(
    live: tuple[TestClient, ServiceState],
) -> None:
    client, _ = live
    sid, auth, created = open_session(client, strategy="random", params={"rate": 0.3})
    assert created["params"] == {"rate": 0.3, "seed": StrategyParams().seed}
    assert client.get(f"/sessions/{sid}", headers=auth).json()["params"] == created["params"]
    _, _, early = open_session(client, strategy="early")
    assert early["params"] == {"n_steps": StrategyParams().n_steps}


@pytest.mark.parametrize(
    ("body", "named"),
    [
        ({"strategy": "oracle"}, "strategy"),
        ({"strategy": "random", "params": {"rate": 1.5}}, "rate"),
        ({"strategy": "goal_aware", "params": {"beta": -0.1}}, "beta"),
        ({"strategy": "early", "params": {"n_steps": -1}}, "n_steps"),
        ({"strategy": "early", "params": {"n_steps": 2.5}}, "n_steps"),
        ({"strategy": "mistake", "params": {"threshold": "high"}}, "threshold"),
        ({"strategy": "random", "params": {"speed": 3}}, "speed"),
        ({"strategy": "goal_aware", "params": {"n_steps": 7}}, "goal_aware does not read n_steps"),
        ({"params": {"beta": 0.5}}, "paper does not read beta"),
        ({"strategy": "always", "params": {"rate": 0.5}}, "always does not read rate"),
        ({"params": []}, "params"),
    ],
)
def test_bad_strategy_or_parameters_are_refused_with_the_reason(
    live: tuple[TestClient, ServiceState], body: dict[str, Any], named: str
) -> None:
    client, _ = live
    r = client.post("/domains/default/sessions", json=body)
    assert r.status_code == 422, r.text
    assert named in r.text


def test_non_finite_parameters_are_refused(live: tuple[TestClient, ServiceState]) -> None:
    client, _ = live
    raw = '{"strategy": "importance", "params": {"threshold": NaN}}'
    r = client.post(
        "/domains/default/sessions", content=raw, headers={"Content-Type": "application/json"}
    )
    assert r.status_code == 422, r.text


class _Nothing:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def test_goal_aware_advice_shown_is_the_advice_given(tmp_path: Path) -> None:
    # a service of its own: the module's service gets random expert data from other tests,
    # and which cells' per-goal advice differs from the pooled theta depends on that data
    with TestClient(create_app(make_settings(tmp_path))) as client:
        grid = client.app.state.service.catalog.get("default").domain  # type: ignore[attr-defined]
        body: dict[str, Any] = {"kappa": 0.0, "strategy": "goal_aware", "params": {"beta": 1.0}}
        sid, auth, _ = open_session(client, **body)
        path = expert_trajectory(grid, grid.start, grid.goals[-1], np.random.default_rng(5))
        events = [{"state": grid.cell(s), "action": ACTIONS[a]} for s, a in path.tolist()]
        got = client.post(f"/sessions/{sid}/events", json=events, headers=auth).json()
        pooled = client.get("/domains/default/prior").json()["theta"]
        own = [
            k for k, d in enumerate(got)
            if d["advise"] and list(d["advice"].values()) != pooled[d["state"][0]][d["state"][1]]
        ]  # fmt: skip
        assert own, "goal-aware advice never differed from the pooled theta on this path"
        # the same events one per request (the single-event path) up to such advice
        sid, auth, _ = open_session(client, **body)
        one = [
            client.post(f"/sessions/{sid}/events", json=e, headers=auth).json()
            for e in events[: own[-1] + 1]
        ]  # fmt: skip
        assert one == got[: own[-1] + 1]
        overview = client.get("/overview", headers=operator(client)).json()["sessions"]
        mine = next(x for x in overview if x["session_id"] == sid)
        assert mine["last_advice"] == {
            "step": one[-1]["step"],
            "state": one[-1]["state"],
            "advice": one[-1]["advice"],
        }


@pytest.mark.parametrize("name", ["threshold", "rate", "beta"])
def test_parameters_are_numbers_not_booleans(
    live: tuple[TestClient, ServiceState], name: str
) -> None:
    client, _ = live
    r = client.post("/domains/default/sessions", json={"params": {name: False}})
    assert r.status_code == 422 and name in r.text


def test_the_schema_s_strategies_and_parameters_are_the_core_s(
    live: tuple[TestClient, ServiceState],
) -> None:
    """One source of truth: the request schema is made from the core's definitions."""
    client, _ = live
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    assert schemas["SessionCreate"]["properties"]["strategy"]["enum"] == list(STRATEGIES)
    schema = schemas["StrategyParams"]
    core = {f.name: f for f in fields(StrategyParams)}
    assert set(schema["properties"]) == set(core)
    assert schema["additionalProperties"] is False
    for name, f in core.items():
        prop = next(p for p in schema["properties"][name]["anyOf"] if p["type"] != "null")
        assert prop["type"] == ("integer" if f.type == "int" else "number")
        assert prop["minimum"] == f.metadata["low"]
        assert prop.get("maximum", math.inf) == f.metadata["high"]
        assert f"Default {f.default}." in schema["properties"][name]["description"]
    read = {p for e in strategies.STRATEGIES.values() for p in e.reads}
    assert read == set(core)  # each is read by one


def test_a_guide_session_on_a_map_too_big_for_guide_is_refused_saying_why(
    live: tuple[TestClient, ServiceState], monkeypatch: pytest.MonkeyPatch
) -> None:
    client, service = live
    rows = ["#######", "#G..#G#", "#.#.#.#", "#...#.#", "###...#", "#S....#", "#######"]
    admin = {"X-API-Key": service.admin_key}
    monkeypatch.setattr(guide_module, "MAX_GUIDE_CELLS", 20)  # 2 destinations x 19 cells
    # the PUT prepares the domain: the guide map cannot be built, the domain is stored
    assert client.put("/domains/small", json={"map": rows}, headers=admin).status_code == 201
    r = client.post("/domains/small/sessions", json={"strategy": "guide"})
    assert r.status_code == 422
    assert "strategy guide" in r.json()["detail"] and "more than 20" in r.json()["detail"]
    monkeypatch.undo()
    # prepared again by the next PUT, under the limit in force then
    assert client.put("/domains/small", json={"map": rows}, headers=admin).status_code == 200
    r = client.post("/domains/small/sessions", json={"strategy": "guide"})
    assert r.status_code == 201 and r.json()["strategy"] == "guide"


def operator(client: TestClient) -> dict[str, str]:
    """The read-only operator key: /overview lists live sessions only for it (or the admin)."""
    state: ServiceState = client.app.state.service  # type: ignore[attr-defined]
    return {"X-API-Key": state.operator_key}
