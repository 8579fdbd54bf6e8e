"""The visitors experiment runs in seconds with a tiny budget, writes its files, repeats the
buildings experiment's tasks for a plain walker, and its floor is the best order of the
destinations (checked against every order); beyond the exact search, a searched order bounds
it from above."""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import cli
from app.domain.generate import generate_building_domain, generate_domain
from app.domain.grid import GridDomain
from app.experiments import buildings, suite, visitors
from app.experiments.output import RunDir

VISITORS = (
    "random", "corridor p=0.5", "optimal q=0.2", "random anywhere", "straight r=5", "optimal",
    "random-avoid positions", "random-avoid q=0.2 j=2 positions",
)  # fmt: skip
TINY: dict[str, Any] = {
    "tasks": 3, "buildings": (24,), "steps": 300, "workers": 1, "progress": False,
    "visitors": VISITORS,
}  # fmt: skip


@pytest.fixture(scope="module")
def floor(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("maps") / "floor.txt"
    path.write_text(generate_building_domain(20, 26, 9, n_goals=3).to_text())
    return path


@pytest.fixture(scope="module")
def tiny(floor: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("visitors")
    return out, visitors.run(visitors.Args(mazes=(floor,), **TINY), RunDir(out))


def test_writes_every_file_and_a_row_per_map_visitor_and_config(
    tiny: tuple[Path, dict[str, Any]],
) -> None:
    out, result = tiny
    for name in ("visitors.json", "visitors.csv", "visitors.md", "visitors.png"):
        assert (out / name).stat().st_size > 0, name
    assert [m["name"] for m in result["maps"]][1] == "floor"
    assert {c["key"] for c in result["configs"]} == {"none", "guide@0.5"}
    assert [v["spec"] for v in result["visitors"]] == list(VISITORS)
    assert len(result["rows"]) == 3 * len(VISITORS) * 2  # two maps and the suite
    for r in result["rows"]:
        assert r["tasks"] == (6 if r["map"] == "suite" else 3)
        assert r["arrived"] == round(r["success"] * r["tasks"])
        assert 0.0 <= r["trapped_share"] <= 1.0
        if r["curve"] == "none":
            assert r["advice_per_task"] == 0 and r["change_success"] == 0
        if r["goals"] == "anywhere" or r["map"] == "suite":
            assert r["arrival_over_floor"] is None
    text = (out / "visitors.md").read_text()
    assert "## guide@0.5 against no advice" in text and "corridor p=0.5" in text
    stored = json.loads((out / "visitors.json").read_text())["rows"]  # NaN stored as null
    assert [(r["visitor"], r["key"], r["success"]) for r in stored] == [
        (r["visitor"], r["key"], r["success"]) for r in result["rows"]
    ]
    for m in result["maps"]:
        assert m["floor"] is not None and m["floor_on_tasks"] is not None
        assert sorted(m["order"]) == list(range(m["goals"]))
        assert m["floor_exact"] is True  # a few destinations: the exact search
        assert m["floor_reach_exact"] is True  # the most any walk reaches in 300 / 4 moves
        assert np.mean(np.array(m["arrival"]) <= 75) <= m["floor_reach"] <= 1
    assert "destinations within 75 moves" in text
    # positions read off against exact ones: "optimal q=0.2" and the positions visitor that
    # jumps have their exact twins here
    assert "## Positions read one cell off against exact positions" in text
    noise = result["noise"]
    scopes = [m["name"] for m in result["maps"]] + ["suite"]
    assert [(r["visitor"], r["exact"], r["map"]) for r in noise] == [
        ("optimal q=0.2", "optimal", m) for m in scopes
    ] + [("random-avoid q=0.2 j=2 positions", "random-avoid positions", m) for m in scopes]
    for r in noise:
        row = find_row(result["rows"], r["map"], r["visitor"])
        exact = find_row(result["rows"], r["map"], r["exact"])
        assert (r["success"], r["success_exact"]) == (row["success"], exact["success"])
        assert r["change"] == pytest.approx(row["success"] - exact["success"])


def find_row(rows: list[dict[str, Any]], scope: str, visitor: str) -> dict[str, Any]:
    return next(
        r for r in rows if r["map"] == scope and r["visitor"] == visitor and r["key"] != "none"
    )


def test_a_plain_walker_repeats_the_buildings_tasks(floor: Path) -> None:
    """The same maps, experts, goals and walker streams as ``experiment buildings``."""
    args = visitors.Args(mazes=(floor,), **{**TINY, "buildings": ()})
    spec = suite.map_suite(args.suite())[0]
    mine = visitors.run_job(args, spec, "random")
    theirs = buildings.run_fixed(
        buildings.Args(mazes=(floor,), buildings=(), tasks=3, steps=300, strategies=("guide",),
                       guide_levels=(), q_tasks=0, progress=False),
        spec, "random",
    )  # fmt: skip
    for key in ("none", "guide@0.5"):
        for measure in ("success", "steps", "advice"):
            np.testing.assert_array_equal(mine[key][measure], theirs[key][measure])


def latency(d: GridDomain, order: tuple[int, ...]) -> int:
    """The sum of the arrivals at the destinations visited in ``order`` from the start."""
    dist = d.goal_distances
    t, at, out = 0, -1, 0
    for j in order:
        t += int(dist[j, d.start] if at < 0 else dist[j, d.goals[at]])
        out, at = out + t, j
    return out


def test_floor_is_the_best_order_of_the_destinations() -> None:
    for seed in range(3):
        d = generate_domain(13, 15, seed, braid=0.3, n_goals=5)
        got = visitors.min_latency_order(visitors.latency_legs(d))
        assert got is not None
        order, arrival = got
        every = itertools.permutations(range(len(d.goals)))
        assert sum(arrival) == min(latency(d, p) for p in every)
        assert latency(d, tuple(order)) == sum(arrival)


def nearest_first(d: GridDomain) -> tuple[int, ...]:
    """The nearest-neighbour order from the start (ties to the lower index)."""
    dist, order, at = d.goal_distances, [], d.start
    left = set(range(len(d.goals)))
    while left:
        j = min(left, key=lambda j: (int(dist[j, at]), j))
        order.append(j)
        left.remove(j)
        at = d.goals[j]
    return tuple(order)


def test_the_searched_order_bounds_the_floor_from_above() -> None:
    for seed in range(6):
        d = generate_domain(15, 17, seed, braid=0.3, n_goals=7)
        legs = visitors.latency_legs(d)
        exact, got = visitors.min_latency_order(legs), visitors.searched_latency_order(legs)
        assert exact is not None and got is not None
        order, arrival = got
        assert sorted(order) == list(range(len(d.goals)))
        assert latency(d, tuple(order)) == sum(arrival)
        assert sum(exact[1]) <= sum(arrival) <= latency(d, nearest_first(d))


def within(d: GridDomain, order: tuple[int, ...], budget: int) -> int:
    """How many destinations the walk along ``order`` reaches within ``budget`` moves."""
    dist = d.goal_distances
    t, at, out = 0, -1, 0
    for j in order:
        t += int(dist[j, d.start] if at < 0 else dist[j, d.goals[at]])
        out, at = out + (t <= budget), j
    return out


def test_the_most_within_a_budget_is_the_best_orders(monkeypatch: pytest.MonkeyPatch) -> None:
    for seed in range(4):
        d = generate_domain(15, 17, seed, braid=0.3, n_goals=6)
        every = list(itertools.permutations(range(len(d.goals))))
        legs = visitors.latency_legs(d)
        got = visitors.searched_latency_order(legs)
        assert got is not None
        order = got[0]
        for budget in (0, 10, 25, 40, 80, 10_000):
            most, exact = visitors.most_within(legs, order, budget)
            assert exact and most == max(within(d, p, budget) for p in every)
            with monkeypatch.context() as m:
                m.setattr(visitors, "MAX_FLOOR_GOALS", 3)
                found, exact = visitors.most_within(legs, order, budget)
            assert not exact and within(d, tuple(order), budget) <= found <= most


def test_a_floor_beyond_the_exact_search_is_marked_as_a_bound(
    floor: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    args = visitors.Args(mazes=(floor,), **{**TINY, "buildings": ()})
    spec = suite.map_suite(args.suite())[0]
    exact = visitors.floor_of(args, spec)
    monkeypatch.setattr(visitors, "MAX_FLOOR_GOALS", 2)  # the map has 3 destinations
    bound = visitors.floor_of(args, spec)
    assert exact["floor_exact"] is True and bound["floor_exact"] is False
    assert bound["floor"] >= exact["floor"]
    reach = visitors.reach_of(args)
    assert reach == 75  # 300 steps at a piece in four
    assert bound["floor_reach_exact"] is False and exact["floor_reach_exact"] is True
    assert np.mean(np.array(bound["arrival"]) <= reach) <= bound["floor_reach"]
    assert bound["floor_reach"] <= exact["floor_reach"]
    d = visitors.place(args, spec).world.domain
    assert isinstance(d, GridDomain)
    assert exact["nearest_first"] == pytest.approx(latency(d, nearest_first(d)) / len(d.goals))
    assert exact["floor"] <= exact["nearest_first"]
    assert visitors._bound(bound, "floor").startswith("≤ ")
    assert not visitors._bound(exact, "floor").startswith("≤")


def test_trapped_moves_count_windows_of_few_cells() -> None:
    pacing = np.array([1, 2, 3, 4] * 30)  # 120 positions on 4 cells: every window trapped
    assert visitors.trapped_moves(pacing) == 120 - 49
    assert visitors.trapped_moves(np.arange(200)) == 0
    assert visitors.trapped_moves(np.array([1, 2, 3, 4, 5] * 20)) == 0  # 5 cells: not trapped
    assert visitors.trapped_moves(np.array([7] * 49)) == 0  # shorter than a window


def test_a_bad_visitor_spec_is_refused_in_one_line(floor: Path) -> None:
    result = CliRunner().invoke(
        cli, ["experiment", "visitors", "--mazes", str(floor), "--visitors", "random p=2"]
    )
    assert result.exit_code == 2
    assert "p (compliance) must be a number from 0 to 1" in result.output
