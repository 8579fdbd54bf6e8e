"""The paper's rule in a building of several floors: experts ride the stairs and lifts on the
quickest routes, the prior learnt from them has six actions, and a lost visitor is told apart
from one who walks with purpose upstairs as on one floor (readable and compiled alike)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.advice.advisor import Advisor, kl_divergence
from app.advice.goals import GoalAwareAdvisor
from app.advice.guide import GuideMap
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.advice.rules import RULES
from app.agents.episodes import run_episode
from app.agents.experts import train_goal_priors, train_prior
from app.agents.explorers import make_explorer
from app.agents.simulate import Simulator
from app.domain.building import Building, D, U
from app.domain.floorplans import generate_floors
from app.domain.generate import generate_building_domain
from app.domain.paths import expert_trajectories
from app.strategies import make_advisor
from app.strategies.stream import StreamAdvisor


@pytest.fixture(scope="module")
def hospital() -> Building:
    return generate_floors(40, 40, 3, np.random.default_rng(3), purpose="hospital", n_goals=3)


def test_experts_take_the_quickest_routes_through_stairs_and_lifts(hospital: Building) -> None:
    b = hospital
    experts = expert_trajectories(b, np.random.default_rng(1), "start", per_goal=3)
    assert len(experts) == 3 * len(b.goals)
    for e in experts:
        s, time = b.start, 0
        for state, action in e.pairs.tolist():
            assert state == s
            time += int(b.durations[s, action])
            s = b.step(s, action)
        assert s == e.goal
        assert time == b.times_to(e.goal)[b.start]  # no quicker way: the fewest moves of time
        if b.cell(e.goal)[0] > 0:  # upstairs: up by a stair or a lift, never down
            assert (e.pairs[:, 1] == U).sum() == b.cell(e.goal)[0]
            assert (e.pairs[:, 1] == D).sum() == 0


def test_a_lost_visitor_is_advised_and_one_walking_upstairs_is_not(hospital: Building) -> None:
    b = hospital
    prior = train_prior(b, np.random.default_rng(2), "anywhere", per_goal=200)
    theta = prior.theta()
    assert theta.shape == (b.n_states, 6)
    stops = np.flatnonzero(b.connection_of >= 0)
    assert (theta[stops].argmax(axis=1) == U).any()  # experts ride up from the ground floor
    tables = AdviceTables.paper(theta)
    upstairs = [g for g in b.goals if b.cell(g)[0] == 2]
    walk = expert_trajectories(b, np.random.default_rng(4), "start", 1)
    purposeful = next(e.pairs for e in walk if e.goal == upstairs[0])
    rng = np.random.default_rng(5)
    lost = []
    s = b.start
    for _ in range(400):
        a = int(rng.integers(6))
        lost.append((s, a))
        s = b.step(s, a)
    for pairs, most, least in ((purposeful, 0, 0), (lost, 400, 20)):
        core, fast = Advisor(tables, 0.5, 300), StreamAdvisor(tables, 0.5, 300)
        assert fast.start(b.start) == core.start(b.start)
        states = np.array([p[0] for p in pairs], dtype=np.int64)
        actions = np.array([p[1] for p in pairs], dtype=np.int64)
        after = b.next_state[states, actions]
        expected = [core.observe(*p) for p in zip(states.tolist(), actions.tolist(),
                                                   after.tolist(), strict=True)]  # fmt: skip
        assert fast.observe_batch(states, actions, after).decisions() == expected
        assert least <= core.advice_count <= most
        for d in expected:
            if d.advise:
                assert d.advice is not None and len(d.advice) == 6


def test_goal_aware_advice_with_no_goal_told_apart_is_the_paper_s_on_six_actions(
    hospital: Building,
) -> None:
    """Goal-aware advice narrows theta by a posterior over the goals; before any goal is ruled
    out (beta 0) theta^w is the pooled prior, so its decisions are the paper's rule's, KL
    scale included, up to rounding; advice has six probabilities."""
    b = hospital
    prior, goals = train_goal_priors(b, np.random.default_rng(6), "anywhere", 40)
    assert goals.goal_counts.shape == (len(b.goals), b.n_states, 6)
    copied = goals.copy(alpha0=2.0)  # as the service copies them: six actions still
    assert copied.n_actions == 6 and np.array_equal(copied.goal_counts, goals.goal_counts)
    tables = AdviceTables.paper(prior.theta())
    paper, aware = Advisor(tables, 0.3, 100), GoalAwareAdvisor(tables, goals, 0.3, 100)
    rng = np.random.default_rng(7)
    s = b.start
    first = [paper.start(s), aware.start(s)]
    assert first[1].kl == pytest.approx(first[0].kl, rel=1e-9, abs=1e-12)
    goal_cells = set(b.goals)
    for _ in range(300):
        a = int(rng.integers(6))
        s2 = b.step(s, a)
        if s in goal_cells or s2 in goal_cells:
            break  # leaving a goal rules it out: the two part from there
        d_paper, d_aware = paper.observe(s, a, s2), aware.observe(s, a, s2)
        assert d_aware.kl == pytest.approx(d_paper.kl, rel=1e-9, abs=1e-12)
        assert d_aware.advise == d_paper.advise or abs(d_paper.kl - 0.3) < 1e-9
        if d_aware.advise:
            assert d_aware.advice == pytest.approx(d_paper.advice, rel=1e-9)
        s = s2


@pytest.mark.parametrize("n_actions", [4, 6])
def test_the_rules_read_the_number_of_actions(n_actions: int) -> None:
    """Importance advises where KL[theta_s || uniform over A] (in four actions' units) reaches
    the threshold; mistake after an action theta_s gave less than the threshold; every rule's
    advice is theta_s, A probabilities."""
    rng = np.random.default_rng(n_actions)
    theta = rng.dirichlet(np.full(n_actions, 0.5), size=30)
    theta = np.maximum(theta, 1e-6)
    theta /= theta.sum(axis=1, keepdims=True)
    tables = AdviceTables.paper(theta)
    params = StrategyParams(threshold=0.3)
    importance = RULES["importance"](tables, 0.5, 50, params)
    mistake = RULES["mistake"](tables, 0.5, 50, params)
    importance.start(0)
    mistake.start(0)
    for _ in range(200):
        s, a, s2 = int(rng.integers(30)), int(rng.integers(n_actions)), int(rng.integers(30))
        d = importance.observe(s, a, s2)
        sure = kl_divergence(theta[s2], np.full(n_actions, 1 / n_actions))
        assert d.advise == (sure * math.log(4) / math.log(n_actions) >= 0.3)
        assert d.advice == (tuple(theta[s2]) if d.advise else None)
        assert mistake.observe(s, a, s2).advise == (theta[s, a] < 0.3)


def test_the_paper_s_rule_leads_random_walkers_upstairs_and_leaves_the_quickest_alone() -> None:
    """The reference loop on a two-floor hospital, destinations upstairs: random-avoid walkers
    (the paper's protocol: an advised walker samples theta_s, six actions) arrive more often
    when advised; the optimal walker takes the quickest route (rides timed) and is never
    advised at kappa 0.5."""
    b = generate_floors(24, 24, 2, np.random.default_rng(3), purpose="hospital", n_goals=2)
    tables = AdviceTables.paper(train_prior(b, np.random.default_rng(2), "anywhere", 200).theta())
    upstairs = [g for g in b.goals if b.cell(g)[0] == 1]
    arrived = {}
    for advised in (False, True):
        rng = np.random.default_rng(11)
        runs = [
            run_episode(b, make_explorer("random-avoid", b), Advisor(tables, 0.5, 300),
                        upstairs[k % len(upstairs)], rng, advised=advised, max_steps=2000)
            for k in range(40)
        ]  # fmt: skip
        arrived[advised] = sum(r.success for r in runs)
        if advised:
            assert all(len(d.advice or ()) in (0, 6) for r in runs for d in r.decisions)
            assert any(a >= U for r in runs for a in r.actions)  # it rides
    assert arrived[True] >= arrived[False] + 5, arrived
    for goal in upstairs:
        rec = run_episode(b, make_explorer("optimal", b), Advisor(tables, 0.5, 300), goal,
                          np.random.default_rng(1))  # fmt: skip
        assert rec.success and rec.advice_count == 0
        assert sum(int(b.durations[s, a]) for s, a in zip(rec.states, rec.actions, strict=True)) \
            == b.times_to(goal)[b.start]  # fmt: skip


def test_nearest_stops_are_the_nearest_by_row_and_column(hospital: Building) -> None:
    """Building.nearest_stops against a search over every cell of the floor."""
    b = hospital
    for s in np.random.default_rng(0).choice(b.n_states, 200, replace=False).tolist():
        f, r, c = b.cell(s)
        for k, action in enumerate((U, D)):
            stops = [t for t in range(b.n_states)
                     if b.cell(t)[0] == f and b.step(t, action) != t]  # fmt: skip
            if not stops:
                assert b.nearest_stops[s, k] == -1
                continue
            near = min(stops, key=lambda t: (abs(b.cell(t)[1] - r) + abs(b.cell(t)[2] - c), t))
            assert b.nearest_stops[s, k] == near
    top = b.n_floors - 1
    assert (b.nearest_stops[b.cells[:, 0] == top, 0] == -1).all()  # no way up from the top
    assert (b.nearest_stops[b.cells[:, 0] == 0, 1] == -1).all()  # nor down from the ground


def test_compass_walkers_in_a_building(hospital: Building) -> None:
    """The wall follower keeps to its floor, a ride keeps a heading, the bug heads for the
    nearest way up and rides it, and a corridor walker takes a stair or lift as a way on."""
    b = hospital
    upstairs = next(g for g in b.goals if b.cell(g)[0] == 2)
    stop = int(b.nearest_stops[b.start, 0])
    near = stop  # a few cells west along the corridor from the way up: in sight of it
    for _ in range(3):
        near = b.step(near, 3)
    assert near != stop and b.nearest_stops[near, 0] == stop
    floors_seen = {}
    for name, start in (("left", b.start), ("corridor", b.start), ("bug", near)):
        e = make_explorer(name, b)
        rng = np.random.default_rng(4)
        e.reset(upstairs, rng)
        s, seen = start, set()
        for _ in range(3000):
            a = e.act(s, rng)
            s2 = b.step(s, a)
            e.observe(s, a, s2)
            seen.add(b.cell(s2)[0])
            s = s2
            if s == upstairs:
                break
        floors_seen[name] = seen
    assert floors_seen["left"] == {0}  # a hand on the wall finds no way up
    assert len(floors_seen["corridor"]) > 1
    assert {0, 1, 2} <= floors_seen["bug"]  # up a floor at a time, to its goal's
    bug = make_explorer("bug", b)
    rng = np.random.default_rng(0)
    bug.reset(upstairs, rng)
    assert bug.policy(stop, rng) == U  # at the nearest way up it rides
    left = make_explorer("left", b)
    left.reset(upstairs, rng)
    heading = left.heading  # type: ignore[attr-defined]
    left.observe(stop, U, b.step(stop, U))
    assert left.heading == heading  # type: ignore[attr-defined]


@pytest.mark.parametrize("floors", [2, 3])
def test_guide_map_detours_are_the_compass_walker_s_fewest_shown_moves(floors: int) -> None:
    """A building's compass detours (the vectorised search over Building.compass_takes)
    against a plain relaxation over the readable rule (GuideMap.compass_moves): the fewest
    moves on a way to each destination that the compass walker would not make by itself."""
    b = generate_floors(20, 20, floors, np.random.default_rng(floors), n_goals=2, room=(3, 5))
    g = GuideMap.of(b)
    assert g.n_actions == 6 and g.floor is not None
    for i, goal in enumerate(g.goals):
        own = np.zeros((b.n_states, 6), dtype=bool)
        for s in range(b.n_states):
            own[s, g.compass_moves(i, s)] = True
            aim, ride = b.compass_aims(np.array([goal]), np.array([s]))
            assert set(g.compass_moves(i, s)) == {
                a for a in range(6) if b.compass_takes(np.array([goal]), np.array([s]), a)[0]
            }, (s, aim, ride)
        best = np.full(b.n_states, np.iinfo(np.int64).max // 2)
        best[goal] = 0
        cost = np.where(own, 0, 1)
        while True:
            via = (best[b.next_state] + cost).min(axis=1)
            via[goal] = 0
            new = np.minimum(best, via)
            if (new == best).all():
                break
            best = new
        np.testing.assert_array_equal(g.detour[i], best)


def test_guide_leads_lost_visitors_upstairs_and_leaves_the_quickest_alone() -> None:
    """On a two-floor hospital, destinations upstairs: guide leads random-avoid walkers and
    bugs there (compiled), advising the ride up where it is (the readable advisor); the
    optimal walker is never advised."""
    b = generate_floors(24, 24, 2, np.random.default_rng(3), purpose="hospital", n_goals=2)
    prior, goal_priors = train_goal_priors(b, np.random.default_rng(2), "start", 5, 1.0)
    sim = Simulator(b, AdviceTables.paper(prior.theta()), goal_priors)
    upstairs = [g for g in b.goals if b.cell(g)[0] == 1]
    for explorer in ("random-avoid", "bug"):
        alone, guided = 0, 0
        for k in range(20):
            goal, rng = upstairs[k % len(upstairs)], np.random.default_rng(k)
            alone += sim.fixed(explorer, goal, rng, advised=False, max_steps=2000).success
            run = sim.fixed(explorer, goal, np.random.default_rng(k), advised=True,
                            strategy="guide", max_steps=2000)  # fmt: skip
            guided += run.success
            assert 100 * run.advice_count <= 45 * run.steps
        assert guided >= 18 and guided >= alone + 10, (explorer, alone, guided)
    rides = []  # where a lost walker's own move at a stop does not lose ground on average,
    for seed in range(4):  # it is left to ride by itself: a few episodes show the advice
        advisor = make_advisor("guide", sim.tables, 0.5, 300, None, goal_priors, sim.guide)
        rec = run_episode(b, make_explorer("random-avoid", b), advisor, upstairs[0],
                          np.random.default_rng(seed), advised=True, max_steps=2000)  # fmt: skip
        assert rec.success
        rides += [d for d in rec.decisions if d.advise and d.advice is not None
                  and int(np.argmax(d.advice)) == U]  # fmt: skip
    assert rides and all(b.step(d.state, U) != d.state for d in rides)  # up, at a stop
    for goal in upstairs:
        run = sim.fixed("optimal", goal, np.random.default_rng(1), advised=True, strategy="guide")
        assert run.success and run.advice_count == 0


def test_apart_bounds_the_moves_between_cells_of_a_building(hospital: Building) -> None:
    """``GuideMap.apart`` on floors (row and column where the rides keep them, the
    destinations' and landmarks' moves) never exceeds the moves between two cells, and the
    compiled ``guide_apart`` gives the same numbers."""
    from app import kernels

    gm = GuideMap.of(hospital)
    assert gm.cells_bound  # a generated building's stops are stacked
    rng = np.random.default_rng(0)
    for v in rng.integers(0, hospital.n_states, 6).tolist():
        dist = hospital.distances_to(v)
        for u in rng.integers(0, hospital.n_states, 30).tolist():
            assert 0 <= gm.apart(u, v) <= dist[u]
            got = kernels.guide_apart(gm.cells, gm.dist, gm.marks, gm.cells_bound, u, v)
            assert got == gm.apart(u, v)


def test_a_building_has_landmarks_on_every_floor() -> None:
    """``marks_for``: MARKS a floor (one floor keeps MARKS), as far as MAX_MARK_CELLS allows;
    a building's guide map holds that many, and its rides' spread a floor."""
    from app.advice import guide

    assert guide.marks_for(10_000, 1) == guide.MARKS
    assert guide.marks_for(10_000, 3) == 3 * guide.MARKS
    assert guide.marks_for(guide.MAX_MARK_CELLS // 10, 40) == 10 < 40 * guide.MARKS
    assert guide.marks_for(10 * guide.MAX_MARK_CELLS, 5) == guide.MARKS  # MARKS at least
    b = generate_floors(32, 32, 3, np.random.default_rng(1), purpose="hospital", n_goals=2)
    gm = GuideMap.of(b)
    assert gm.marks.shape == (3 * guide.MARKS, b.n_states)
    floors = {b.cell(int(np.flatnonzero(row == 0)[0]))[0] for row in gm.marks}
    assert floors == {0, 1, 2}  # the farthest cells: some on every floor
    # generated stairs take 18 moves of time a floor, lifts 12: a quickest walk by lift may
    # take 6 moves more than the fewest for each floor it rides
    assert gm.ride_spread == 6 and gm.arrays[11] == 6
    assert GuideMap.of(generate_building_domain(24, 24, 1)).ride_spread == 0  # one floor


def test_every_shortest_walk_from_the_entrance_of_a_hospital_passes_the_purpose_bound() -> None:
    """The purpose test's longest bound (a walk of n moves is a shortest path give or take
    n / 4, as far as ``GuideMap.apart`` tells) holds for the shortest walk from the entrance
    to every cell of the experiments' 3-floor 64 x 64 hospital with 2 destinations a floor.
    With 8 landmarks for the whole building it failed for 906 of its 8,041 cells farther
    than 24 moves, so an optimal visitor bound for one of them was advised on its way."""
    from app.advice import guide

    b = generate_floors(64, 64, 3, np.random.default_rng(236587310), purpose="hospital",
                        n_goals=2)  # fmt: skip
    gm = GuideMap.of(b)
    moves = b.distances_to(b.start)
    far = np.flatnonzero((moves > guide.PURPOSE_RUN) & (moves <= guide.PURPOSE_WALK))
    assert far.size > 8000
    for v in far.tolist():
        n = int(moves[v])
        assert gm.apart(b.start, v) >= n - max(guide.PURPOSE_LONG_SLACK, n // 4), b.cell(v)


def test_quickest_walks_by_lift_to_places_that_are_no_destination_are_left_alone() -> None:
    """Visitors walking the quickest way (by lift where it saves time, so more moves than
    the fewest) to cells that are no destination, on a generated 5-floor 32 x 32 hospital
    with 2 destinations a floor (seed 236587310): guide never advises them (compiled).
    Before a ride's spread was allowed for in the purpose test, walks that rode three floors
    by lift were taken for lost and advised on the top floors: these 60 visitors were given
    144 pieces with 8 landmarks and no spread (the commit before)."""
    b = generate_floors(32, 32, 5, np.random.default_rng(236587310), purpose="hospital",
                        n_goals=2)  # fmt: skip
    prior, goal_priors = train_goal_priors(b, np.random.default_rng(2), "start", 10, 1.0)
    sim = Simulator(b, AdviceTables.paper(prior.theta()), goal_priors)
    rng = np.random.default_rng(0)
    upstairs = np.flatnonzero(b.cells[:, 0] >= 3)
    places = [int(c) for c in rng.choice(upstairs, 60, replace=False) if c not in b.goals]
    given = [sim.fixed("optimal", c, np.random.default_rng(i), advised=True, strategy="guide",
                       max_steps=2000).advice_count for i, c in enumerate(places)]  # fmt: skip
    assert sum(given) == 0, given
