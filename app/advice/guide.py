"""``guide``: advice that leads a lost explorer to a destination of the map (beyond the paper).

The paper's advisor can only repeat what experts did where they went: in a cell no expert
visited theta is uniform and no advice is possible, and its theta pools every destination, so
it can lead into another destination's dead end. A building knows more: its map and its
destinations. ``guide`` keeps a posterior over what the explorer is doing, with these models of
its next action ``a`` at ``s`` (docs/ARCHITECTURE.md has the equations beside the paper's)::

    L4      lost, any action:                (1/4)'
    LO      lost, any open move:             lo(a | s) = (1 - b) open(s, a) / n_open(s) + b/4
    WL, WR  lost, a hand on the wall:        (1 - slack) [a = w(s, h)]' + slack lo(a | s)
    LA      lost, never turning back:        la(a | s) = (1 - b) ahead(s, a) + b/4
    LS      lost, straight on:               (1 - b) [a = h] + b/4 where h is open, else la
    D4_g    on its way to destination g:     (1 - slack) pi_g(a | s)' + slack/4
    DO_g    the same, never into a wall:     (1 - slack) pi_g(a | s)' + slack lo(a | s)
    C_g     heading for g as the crow flies: (1 - slack) c_g(a | s)' + slack lo(a | s)

* ``w(s, h)``: the move of someone keeping the left (WL) or right (WR) hand on the wall,
  heading ``h`` (the last move that moved).
* ``ahead(s, a)``: uniform over the open moves but back (against ``h``) where another is
  open and it has moved, over the open moves otherwise: a lost walker that goes on along
  corridors and streets (the corridor walker), which LO explains poorly (it expects a step
  back as often as any other) and the destinations' models explained instead, a stretch of
  street at a time. LS goes straight on until a wall, then as LA (the straight walker): with
  LA only, advice to go on as it goes is worth a piece in every room.
* ``pi_g``: uniform over the moves that shorten the BFS distance to ``g``, each weighted by
  1 + the experts' goal-``g`` count of (s, a), so that among shortest moves the experts'
  routes are preferred; at ``g`` itself, or where ``g`` cannot be reached, uniform over the
  open moves.
* ``c_g``: the move of someone who heads for where ``g`` is (the paper's "bug"): along the
  axis of the larger row or column difference if that way is open, else along the other axis
  if that way is open (both on a tie); where neither is, uniform over the open moves.
* ``'``: on a move where the last decision advised, each of these explorers, lost or not
  (LO, LA and LS: their rule, in their own evidence; L4: any action),
  takes the advice or its own way, half each (its rule averaged with the advice): they
  follow advice, and those that have a way of their own go back to it when it stops, so a
  detour must be advised step by step. Taking a piece is thus no evidence either way of
  being lost (when the lost models did not take advice, every piece taken counted for the
  destinations' models, and a walker led one move in six was soon taken for one on its way
  and left alone; while L4 alone took none, a walker that bumps into walls, explained by L4
  only, was taken for one on its way and its budget filled unspent).

**A building of several floors** (six actions, ``U`` and ``D`` the rides): the same models
over every action (each ``/4`` above reads ``/A``: L4, the bumps, the slack, the spread, and
delta4's ``n_open / A``). Distances are BFS moves, a ride one move, so guide leads by the
connection nearest in moves, stairs or lift, and not the quickest in time where the two differ
(the experts' counts weight the ways among the fewest moves). A heading is a compass move (a
ride keeps it), so the wall followers WL and WR never ride; C_g is the bug's rule on floors
(``Building.compass_aims``: on another floor than g's, the nearest stop with a way towards g's
floor, and there the ride), and its detours the same search over it. :meth:`GuideMap.apart`
adds the row plus column difference only where rides keep row and column. The value is in
four actions' units, as the paper's rule's KL is (times log 4 / log A, ``kl_scale``: a kappa
means the same on one floor and on several). The compiled kernels read the floors, and the
compass moves of every cell and destination worked out once (:func:`compass_table`), in
:attr:`GuideMap.arrays` and make the same decisions; the service searches a guide map, a
building's too, with compiled searches that do not hold the GIL (``kernels.guide_distances``,
``guide_detours``, one floor or several), in the worker thread of a PUT.

The evidence fades with time constant W, the session's window::

    L_k  <-  lam L_k + log P(a | s, k)            lam = 1 - 1/W
    P(k | H)  ~  exp(L_k) P(k)                    P(L4) = ... = P(LS) = p_lost / 6,
                                                  3 n_alive P(D4_g) = ... = 1 - p_lost

A destination is ruled out once the explorer stood on it and went on (its task would have
ended there), if the last move can have led there: a position read one cell off, which the
last move cannot have led to, rules nothing out. When positions are walked
(``/positions``), a position read off onto a destination is walked as a visit, so a first
visit only *sets a destination aside* (out like a ruled-out one); once none is left, those
set aside come back, and a second visit rules one out. Once every one is ruled out, the
explorer is bound somewhere else (it passed every destination): nothing more is advised.
A lost explorer is led to a *target* T: the first destination of the best walk from where
it is through every destination not ruled out (it could be going to any of them), planned
again when T is ruled out. For one taken for a walker whose own moves have no drift
(P(L4 | H) + P(LO | H) at least ``DRIFTLESS``) the best walk is the one with the least sum of
arrivals at the destinations, each as likely to be its own (what the visitors' floor
measures); for any other, the shortest walk (one that keeps its heading doubles back less
along it: corridor walkers on Berlin_0_256 arrived in 93% of 100 tasks led along it, 70% led
in the order of the least sum of arrivals). With P(lost | H) the sum over L4, LO, WL, WR, LA, LS::

    theta_s     = P(lost | H) r_T(s) + sum_g [P(D4_g | H) + P(DO_g | H)] pi_g(s)
                                     + sum_g P(C_g | H) pc_g(s)
    P(A | s, H) = sum_k P(k | H) P(A | s, k)
    value       = KL[theta_s || P(A | s, H)] (1 + P(lost | H) delta_T(s)) / price
                  (with L4's share of P(lost | H) weighted by delta4_T(s) instead)
    advise  iff  value >= kappa and t >= 1; the advice: (1 - spread) [a = argmax theta_s]
                                                         + spread/4
    price       = (ADVICE_BURST / t) ** ADVICE_POWER    t: pieces saved of the budget

* ``r_T``: one shortest move towards T (the heaviest of ``pi_T``; the heading on a tie).
  Where the map has lead values (:func:`lead_values`), for one taken for a lost walker that
  keeps a heading, rather for LA than for LS: of the shortest moves, the one after which the
  lead value (from the heading it leaves the walker with) is least, the heaviest's on a tie.
  A walker that never turns back keeps the way a piece gives it, so of two shortest moves
  the one into the corridor that goes on towards T is worth more than the one into a room
  it leaves by another door (corridor walkers on the 5-floor 64 x 64 hospital: 91% -> 98%
  of 400 tasks arrived, docs/RESULTS.md).
* ``pc_g``: the way to ``g`` for someone who moves as ``c_g``: the moves after which the
  fewest moves it would not make by itself remain (:func:`~app.domain.grid.compass_detours`),
  its own moves first.
* ``delta_T(s)``: how far a random open move from ``s`` takes a lost explorer from T, on
  average (BFS distance); advice saves 1 + delta_T moves where it saves 1 in the open, so the
  paper's KL (eq. (3)'s stand-in for the benefit) is weighted by it. ``delta4_T(s)``, the
  same over all four actions (a bump changes nothing: ``delta_T n_open / 4``), for L4: where
  every open move leads towards T a random open move costs nothing, but one stuck against
  the wall there gains a move a piece (with ``delta_T`` for every lost model its value was 0).
* the advice budget: ``t`` grows by ``ADVICE_RATE`` (1/4) each decision up to
  ``ADVICE_BURST`` (8), starts at 1 and a piece spends 1, so a session gets at most one piece
  in four decisions (and one more), whatever kappa; the price (1 with the budget full,
  64 with one piece left) keeps the last pieces for the decisions worth most: a lost walker
  in the open is worth a piece at nearly every move, and a budget spent first come, first
  served leaves none for where the way turns. (A walker whose own moves have no drift gains
  at most one step a piece; one that never turns back keeps the way it is given.) Two
  exceptions: one taken for a walker with a rule of its own (a hand on the wall or the
  compass: P(WL | H) + P(WR | H) + P(C_g | H) summed over g at least 1/2) is shown its
  detours whole, at no price and into debt (``t`` below 0, paid back before any more
  advice), for it goes back to its rule and a detour given by halves is undone; and a piece
  not taken by one that takes only some (P(compliance < PARTLY) at least 1/2) is given back,
  so the budget counts the pieces taken. And a piece for one taken for a walker whose own
  moves have no drift (P(L4 | H) + P(LO | H) at least ``DRIFTLESS``) goes, while the budget is
  not full, only where its own move loses ground (``delta_T(s) > 0``; the mean of delta_T
  over a map's cells is 0 where every move can be walked back), at no price and keeping
  ``ADVICE_KEEP`` piece in hand; elsewhere only with the budget full. The price alone told
  delta 0 from delta 1/6 too weakly (KL x (1 + delta) varies more with KL): random walkers got
  a third of their pieces where their own moves did not lose ground. One taken for a lost
  walker that keeps a heading (P(LA | H) + P(LS | H) at least ``HEADED``, and not for one
  without drift) is given its pieces so too, with its own move's mean change taken from its
  heading, as LA and LS make it (weighted by their shares): in a corridor that leads away from
  T its own move loses a step at every cell though delta_T there is 0 (one way on, one back),
  and with the price it was led back only once the budget was nearly full. Where the map has
  lead values (:func:`lead_values`: the mean moves to T of a walker that never turns back, led
  at ``LEAD_PRICE`` moves a piece) and the explorer is taken to take what it is given
  (P(compliance < PARTLY) below 1/2: the values' leads are taken), "loses ground" is reckoned
  over its way, not its next move: a piece below a full budget goes where the mean value
  after its own move, from its heading, exceeds the value after r_T by more than
  LEAD_PRICE. A corridor walker keeps the
  way it is given: a piece that turns it into the right corridor saves the corridor, one in
  an open room about a move (on the 5-floor 64 x 64 hospital a lead that gave its pieces
  where the next move lost ground got corridor walkers there in 88% of tasks, one that spent
  the same budget exactly, leg by leg, in 96%: docs/RESULTS.md).

How far this explorer takes advice is learned per session. After each piece, whether its
move was the advised one is weighed against the chance of that move anyway (``m``, P(A | s, H)
of the advised move at the decision), over compliance levels c_j = (j + 1/2) / L::

    Lc_j  <-  f Lc_j + log (c_j + (1 - c_j) m)        it took the advised move
    Lc_j  <-  f Lc_j + log ((1 - c_j) (1 - m))        it did not
    P(c_j | H) ~ exp(Lc_j)                            (uniform prior, mean 1/2; f = 0.97)

An explorer whose compliance is below ``IGNORED`` (0.25) with probability at least ``SURE``
(0.7) is taken to ignore advice and gets at most one piece every ``BACKOFF`` (25) decisions,
the piece that lets it show otherwise; once that probability falls below ``RELEASE`` (0.3:
it takes them), advice comes as before. The estimate gates advice rather than
scaling its value: scaling (value x mean compliance / 0.5) gave visitors who take half the advice
less of it and longer walks, and never advised again one estimated to ignore it, who then
could not show that it takes it (docs/RESULTS.md, "Advice that is not taken").

Pieces taken in a row (a chain of k) are followed further: if the explorer's own moves
after them lead back to where the chain began within k moves, they undid it; after k own
moves elsewhere it is kept. A piece taken where the first own move after the chain took back
its last piece interrupts an undoing: that chain counts as undone too (else a visitor going
its own way, led two cells off it, stepping back one and led off again, was neither undoing
nor keeping any chain, and was advised the same detour again and again). An explorer that
undid ``UNDO_RUN`` (4) chains in a row is held back the same way until it keeps one, or
until its own moves, none of them undoing a chain and no piece taken since it left, bring
it back to where it undid the last (it circles there, as a bug in a pocket does, rather
than goes its own way; one led away and back, or undoing the next detour there, does not
circle).
One bound for a place of its own, taken for one bound for a listed destination, that takes
the advice and goes back to its way, is not advised the same detour again and again. A lost
walker undoes a chain only when its own moves happen to retrace it: four one-piece chains
in a row come to one in 256 in the open, one in 16 in a corridor for one that never bumps
into walls.

A visitor bound for a place that is not a listed destination fits no destination's model, and
the lost models would lead it; but it walks with a purpose, and a lost one does not: lost
walkers dither (a step back), bump into walls and circle. So a visitor is left alone while its
last ``PURPOSE_RUN`` (24) moves were a shortest path give or take ``PURPOSE_SLACK`` (2) moves,
its last ``PURPOSE_LONG`` (48) give or take ``PURPOSE_LONG_SLACK`` (6) and its last
``PURPOSE_WALK`` (256) give or take a quarter of their number, with no move into a wall among
the last 48 (within the slack one would pass): one that goes straight until a wall and turns
there (a lost "straight" walker) passes the first test for a while and fails the longer ones
once it comes back. Which walks are shortest paths the map tells without a search per session:
a walk of k moves from u to v is one when k is at most a lower bound on the moves between them
(:meth:`GuideMap.apart`: the larger of the row plus column difference and, for each
destination and each landmark, ``MARKS`` a floor, the difference of their BFS distances to
it); the bound can fall short of the true distance, more so over longer walks, hence the
slacks. In a building the quickest way can be more moves than the fewest (a lift farther
than the stairs, quicker a floor), so each slack grows by ``GuideMap.ride_spread`` moves for
each floor between the walk's ends. Before any advice the walk counts
from the first decision (one walking its way from the start is not told otherwise); after a
piece of advice only once ``PURPOSE_RUN`` moves were walked since, and not while it walks all
along the way to the target, or while each of its moves since the piece was the one the
advice would have been at the step before (given or not), so a visitor being led, or walking
the way it would be led, is led on where the way turns. The bug, heading for its
destination as the crow flies, is left alone too while its way is straight, and shown the way
once it circles in a pocket. (The constants were chosen on maps that are not in the suite,
from how often the rule fails the walks of optimal visitors bound anywhere, about one step in
a hundred at most, and passes those of straight walkers, as seldom as that allows;
docs/RESULTS.md has the suite's figures.)

A competent explorer is explained by some D_g, so the prediction already is what it should do
and nothing is said; a lost one is explained by a lost model and is led, most insistently
where a random move costs most; one that heads for its destination by the compass is explained
by C_g and is shown only the moves it would not make. P(M1 | H) is reported as 1 - P(lost |
H), and the value compared with kappa as the decision's KL. This is plain Python in a fixed
order; app/kernels.py's guide_decide, guide_append and guide_stream are the same arithmetic,
compiled, and the tests compare them bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from itertools import pairwise

import numpy as np

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, Advisor, Decision
from app.advice.models import AdviceTables, kl_scale
from app.advice.params import StrategyParams
from app.advice.priors import GoalPriors
from app.arrays import ByteArray, Float32Array, FloatArray, IntArray
from app.domain.building import Building, Domain, n_floors
from app.domain.grid import (
    N_ACTIONS,
    Takes,
    bfs_distances_each,
    compass_detours_each,
    compass_takes,
)
from app.domain.tours import searched_order

#: probability mass the open-moves lost model gives to bumping into walls
LOST_BUMP = 0.02
#: the lost models before the destinations' in a session's evidence: L4, LO, WL, WR (LA and
#: LS come after the destinations', so that sessions written before them read on)
N_LOST = 4
#: most destinations a tour is planned through exactly (2^n n^2 steps); beyond, through up to
#: MAX_SEARCHED_TOUR of them by local search (the nearest first, improved on the sum of the
#: arrivals, at most TOUR_ROUNDS rounds of about 4 n^3 steps each), and beyond that the
#: nearest. On the suite's hospitals (17-40 destinations) 4 rounds chose the same first
#: destination as 32 in every one of 1,784 cases sampled; at 48 destinations a choice takes
#: about 2.5 ms compiled (benchmarks/bench_tour.py)
MAX_TOUR = 10
MAX_SEARCHED_TOUR = 48
TOUR_ROUNDS = 4
#: most destinations x states a guide map holds (its distances and detours: 16 bytes each)
MAX_GUIDE_CELLS = 16_777_216
#: cells besides the destinations whose BFS distances tighten :meth:`GuideMap.apart`'s lower
#: bound (landmarks: each the free cell farthest from the destinations and the ones before;
#: 8 bytes a cell each), MARKS a floor: a building of F floors has F x MARKS (its walks
#: between floors are bound well only by landmarks on their floors), as far as MAX_MARK_CELLS
#: landmarks x states allow (MARKS at least)
MARKS = 8
MAX_MARK_CELLS = 4_194_304


def marks_for(n_states: int, n_floors: int) -> int:
    """How many landmarks a guide map of ``n_states`` states on ``n_floors`` floors has
    (:data:`MARKS` a floor, as far as :data:`MAX_MARK_CELLS` allows; MARKS at least)."""
    return max(MARKS, min(MARKS * n_floors, MAX_MARK_CELLS // max(n_states, 1)))


#: how far the explorer takes advice, per session: a posterior over COMPLY_LEVELS compliance
#: levels c_j = (j + 1/2) / COMPLY_LEVELS (uniform prior, mean 1/2), its evidence fading by
#: COMPLY_FADE per piece of advice (about the last 30 pieces count)
COMPLY_LEVELS = 10
COMPLY_FADE = 0.97
#: an explorer whose compliance is below IGNORED with posterior probability at least SURE is
#: taken to ignore advice: at most one piece every BACKOFF decisions (4 per 100 steps) until
#: its moves show that it takes advice again (that probability below RELEASE)
IGNORED = 0.25
SURE = 0.7
RELEASE = 0.3
BACKOFF = 25
#: an explorer whose own moves undid UNDO_RUN chains of advice in a row (a chain: pieces
#: taken in a row; undone: back where it began within as many moves) is held back as one
#: that ignores advice, until it keeps one or comes back there by itself
UNDO_RUN = 4
#: the advice budget: ADVICE_RATE pieces a decision at most (one in four), saved up to
#: ADVICE_BURST pieces while none is needed, a session starting with one; with t pieces
#: saved a piece's value is divided by the price (ADVICE_BURST / t) ** ADVICE_POWER before
#: it is compared with kappa, so that where advice is scarce it goes where it is worth most
ADVICE_RATE = 0.25
ADVICE_BURST = 8.0
ADVICE_POWER = 2.0
#: P(L4 | H) + P(LO | H) from which an explorer is taken for one whose own moves have no
#: drift: led in the order of the least mean arrival, its pieces where its own move loses ground
DRIFTLESS = 0.5
#: P(LA | H) + P(LS | H) from which an explorer is taken for a lost walker that keeps a
#: heading (never back but in a dead end; straight on): its pieces where its own move, from its
#: heading, loses ground on average, as a walker's without drift
HEADED = 0.5
#: for such an explorer, where the map has them (:attr:`GuideMap.lead`): a piece below a full
#: budget where it saves more than LEAD_PRICE moves, as :func:`lead_values` reckons a walk
#: that keeps a heading led at that price a piece (its own moves on the way counted, not only
#: the next one: a piece that turns it into the right corridor saves the corridor)
LEAD_PRICE = 8.0
#: :func:`lead_values`' sweeps end once no value changes by LEAD_TOL moves, or after
#: LEAD_SWEEPS; a map holds them while destinations x states is at most MAX_LEAD_CELLS
#: (16 bytes each)
LEAD_TOL = 0.1
LEAD_SWEEPS = 2_000
MAX_LEAD_CELLS = 2_500_000
#: pieces such an explorer's budget keeps in hand below full (so at most a quarter as many
#: pieces as moves over a task, the first included)
ADVICE_KEEP = 1.0
#: a piece not taken is given back to the budget of an explorer whose compliance is below
#: PARTLY more likely than not (one that takes some advice: the budget counts what it takes)
PARTLY = 0.75
#: the chance that an explorer's own move is the advised one, kept within these bounds
CHANCE_MIN, CHANCE_MAX = 0.01, 0.99
#: an explorer whose last PURPOSE_RUN moves since the last piece of advice were a shortest
#: path (:meth:`GuideMap.apart`'s bound, the walk measured where it falls short) walks with a
#: purpose: it is not advised (lost explorers dither, bump and circle); before any advice
#: fewer count, after a piece it is judged once it walked PURPOSE_RUN moves (one being led is
#: led on)
PURPOSE_RUN = 24
#: ... give or take PURPOSE_SLACK moves: a visitor may step aside now and then, and a lost
#: explorer's run falls shorter (one step back costs two)
PURPOSE_SLACK = 2
#: ... and its last PURPOSE_LONG moves (all, if fewer) one give or take PURPOSE_LONG_SLACK:
#: a lost walker can go straight for a while and turn only at walls, but over longer it
#: comes back (the bound is looser over longer walks, hence the larger slack)
PURPOSE_LONG = 48
PURPOSE_LONG_SLACK = 6
#: ... and its whole walk (its last PURPOSE_WALK moves, all if fewer) give or take a
#: PURPOSE_WALK_PART-th of its length (PURPOSE_LONG_SLACK at least): on streets and halls of
#: a hundred cells a lost straight walker comes back only after many more than 48 moves
PURPOSE_WALK = 256
PURPOSE_WALK_PART = 4
#: where the map's bound (:meth:`GuideMap.apart`) falls short over the last PURPOSE_RUN or
#: PURPOSE_LONG moves, the walk is measured exactly (:meth:`GuideMap.within`), a search that
#: queues at most PURPOSE_SEARCH cells (beyond, the bound's verdict stands: a walk not shown
#: to be a shortest path). Measured on the suite's 10 one-floor maps: a shortest walk was
#: shown so within 27 cells; a search that finds a shorter walk may need more (up to 195),
#: but giving up decides as finding it does
PURPOSE_SEARCH = 128
#: a destination's doubt (``GuideAdvisor.doubt``): set aside after its first visit (a
#: position read off, walked, is a visit), or brought back once every other one was out;
#: 0: neither (alive, or ruled out)
SET_ASIDE, BROUGHT_BACK = 1, 2


#: (next_state (S, A), cells (S, 2) or (S, 3), destinations, a building's nearest_stops or
#: None) -> (distances (G, S), detours (G, S), compass moves (S, G): :func:`compass_table`)
Searches = Callable[
    [IntArray, IntArray, tuple[int, ...], IntArray | None],
    tuple[IntArray, IntArray, ByteArray],
]
#: (next_state (S, 4), targets) -> the BFS distance from every state to each target (k, S)
Distances = Callable[[IntArray, IntArray], IntArray]
#: (next_state (S, A), open moves per state (S,), distances (G, S)) -> :func:`lead_values`
Leads = Callable[[IntArray, IntArray, IntArray], Float32Array]


def lead_values(next_state: IntArray, n_open: IntArray, dist: IntArray) -> Float32Array:
    """(G, S, 4) float32: for each destination, state and heading, the mean moves to the
    destination of a walker that never turns back but in a dead end (LA's rule: uniform over
    the open moves but back, back only where nothing else is open; a ride keeps the heading),
    led by a shortest move wherever that is worth a piece at ``LEAD_PRICE`` moves::

        V(s, h) = min(1 + mean over its own moves a of V(s_a, h_a),
                      1 + LEAD_PRICE + min over shortest moves a of V(s_a, h_a))

    0 at the destination and where it cannot be reached. Gauss-Seidel sweeps over the states
    in the order of their distance to it, from the walk led at every move, (1 + LEAD_PRICE) x
    the distance, down, until no value changes by ``LEAD_TOL`` or after ``LEAD_SWEEPS``
    sweeps. Plain Python (slow): ``kernels.guide_lead_values`` makes the same sweeps."""
    n_goals, n_states = dist.shape
    k = next_state.shape[1]
    out = np.zeros((n_goals, n_states, 4), dtype=np.float32)
    for g in range(n_goals):
        dt = [int(x) for x in dist[g]]
        order = [int(c) for c in np.argsort(dist[g], kind="mergesort")]
        v = [[(1.0 + LEAD_PRICE) * dt[c] if dt[c] > 0 else 0.0] * 4 for c in range(n_states)]
        for _ in range(LEAD_SWEEPS):
            change = 0.0
            for c in order:
                here = dt[c]
                if here <= 0 or int(n_open[c]) == 0:
                    continue
                for h in range(4):
                    back = (h + 2) % 4
                    ahead = int(n_open[c]) > 1 and int(next_state[c, back]) != c
                    own, n, led = 0.0, 0, math.inf
                    for a in range(k):
                        u = int(next_state[c, a])
                        if u == c:
                            continue
                        hu = a if a < 4 else h
                        if dt[u] == here - 1 and v[u][hu] < led:
                            led = v[u][hu]
                        if ahead and a == back:
                            continue
                        own += v[u][hu]
                        n += 1
                    best = min(1.0 + own / n, 1.0 + LEAD_PRICE + led)
                    change = max(change, abs(best - v[c][h]))
                    v[c][h] = best
            if change < LEAD_TOL:
                break
        out[g] = np.array(v, dtype=np.float32)
    return out


def ride_spread(building: Building) -> int:
    """The most moves of time a ride of ``building`` takes a floor less than another (0
    without rides): the rides' time a floor, largest less least, rounded up."""
    rides = building.rides
    if rides.shape[0] == 0:
        return 0
    floors = np.abs(building.cells[rides[:, 1], 0] - building.cells[rides[:, 0], 0])
    per = rides[:, 2] / np.maximum(floors, 1)
    return math.ceil(float(per.max() - per.min()))


def _bfs_each(next_state: IntArray, targets: IntArray) -> IntArray:
    return bfs_distances_each(next_state, [int(t) for t in targets])


def landmarks(next_state: IntArray, dist: IntArray, n: int, distances: Distances) -> IntArray:
    """The BFS distances (k, S), k <= n, to ``n`` landmarks, chosen one at a time: the cell
    farthest from the nearest of the destinations (``dist``, (G, S), -1: unreachable) and the
    landmarks before (the lowest state on a tie), while one is farther than 0. Cells that no
    destination reaches are never chosen."""
    big = np.iinfo(np.int64).max
    near = np.where(dist >= 0, dist, big).min(axis=0, initial=big)
    near = np.where(near == big, -1, near)  # -1: no destination reaches it
    out = []
    for _ in range(n):
        far = int(np.argmax(near))
        if near[far] <= 0:
            break
        row = np.asarray(distances(next_state, np.array([far], dtype=np.int64)), dtype=np.int64)
        out.append(row[0])
        near = np.where(row[0] >= 0, np.minimum(near, row[0]), near)
    shape = (len(out), next_state.shape[0])
    return np.ascontiguousarray(np.array(out, dtype=np.int64).reshape(shape))


#: the order :meth:`GuideMap.compass_moves` lists a state's own moves in: the vertical move
#: before the horizontal one (on a tie), the rides (``U``, ``D``) alone
_COMPASS_ORDER = (0, 2, 1, 3, 4, 5)


def compass_table(
    n_states: int, n_actions: int, goals: tuple[int, ...], takes: Takes
) -> ByteArray:  # fmt: skip
    """:meth:`GuideMap.compass_moves` of every state (rows) and destination (columns), each
    as one byte: the first move + 1 in its low four bits, the second + 1 in its high four (0:
    none), what the compiled decisions read instead of working the compass out at every
    decision. ``takes``: the rule of one's own moves that the compass detours are searched
    over (:func:`~app.domain.grid.compass_takes` on one floor, ``Building.compass_takes``)."""
    states = np.arange(n_states, dtype=np.int64)
    out = np.zeros((n_states, len(goals)), dtype=np.uint8)
    for g, goal in enumerate(goals):
        targets = np.full(n_states, goal, dtype=np.int64)
        first = np.full(n_states, -1, dtype=np.int64)
        second = np.full(n_states, -1, dtype=np.int64)
        for a in (a for a in _COMPASS_ORDER if a < n_actions):
            take = takes(targets, states, a)
            second = np.where(take & (first >= 0), a, second)
            first = np.where(take & (first < 0), a, first)
        out[:, g] = (first + 1) | ((second + 1) << 4)
    return out


#: a guide map without lead values (:attr:`GuideMap.lead`)
_NO_LEADS = np.zeros((0, 0, 4), dtype=np.float32)
#: a one-floor map's floors, as app/kernels.py reads them (none)
_NO_FLOOR = np.zeros(0, dtype=np.int64)


class GuideError(ValueError):
    """The domain cannot be guided (no destination, or too many destinations x states)."""


@dataclass(frozen=True, eq=False)
class GuideMap:
    """What ``guide`` reads of a domain: its moves, the BFS distance from every state to every
    destination, and the experts' per-destination counts (zeros where there are none)."""

    next_state: IntArray  # (S, 4)
    n_open: IntArray  # (S,) open moves per state
    cells: IntArray  # (S, 2) row, column
    dist: IntArray  # (G, S), -1 where unreachable
    detour: IntArray  # (G, S) fewest moves against the compass on a way there, -1: none
    goal_of_state: IntArray  # (S,) destination index, -1 elsewhere
    counts: FloatArray  # (G, S * A) experts' goal counts
    goals: tuple[int, ...]
    marks: IntArray  # (L, S) distances to the landmarks (:func:`marks_for`, :func:`landmarks`)
    #: (S, G) :meth:`compass_moves` of every state and destination, as the kernels read them
    #: (:func:`compass_table`)
    compass_of: ByteArray
    #: a building of several floors (None, None on one floor): each state's floor, and
    #: ``Building.nearest_stops``, the compass's way to another floor (:meth:`compass_moves`)
    floor: IntArray | None = None
    stops: IntArray | None = None
    #: whether a walk's row plus column difference bounds its moves (:meth:`apart`): on one
    #: floor, and in a building whose rides keep row and column
    cells_bound: bool = True
    #: in a building, the most moves of time a ride takes a floor less than another ride
    #: (0 on one floor): a quickest walk may take up to that many moves more than the fewest
    #: for each floor it rides (:attr:`GuideAdvisor.purposeful`)
    ride_spread: int = 0
    #: (G, S, 4) :func:`lead_values` (float32), or (0, 0, 4) where the map was made without
    #: them (``leads``) or is too large for them (MAX_LEAD_CELLS): then a walker that keeps a
    #: heading is given its pieces where its next move loses ground
    lead: Float32Array = field(default_factory=lambda: _NO_LEADS)

    @classmethod
    def of(
        cls, domain: Domain, goal_priors: GoalPriors | None = None,
        searches: Searches | None = None, distances: Distances | None = None,
        leads: Leads | None = None,
    ) -> GuideMap:  # fmt: skip
        """``domain``'s guide map (:class:`GuideError` first if it cannot have one), with the
        experts' counts of ``goal_priors``. ``searches(next_state, cells, goals, stops)``:
        the distances and detours of every destination, (G, S) each, and the compass moves
        (S, G), by another implementation of the same searches (the service's compiled ones;
        ``stops`` is a building's ``nearest_stops``, None on one floor); by default
        :attr:`GridDomain.goal_distances`, :func:`compass_detours_each` (in a building,
        :func:`bfs_distances_each` and the building's compass) and :func:`compass_table`.
        ``distances``:
        the searches of the landmarks (:func:`landmarks`), by default
        :func:`~app.domain.grid.bfs_distances_each`. ``leads``: :func:`lead_values` or the
        same sweeps compiled (``kernels.guide_lead_values``), made while destinations x states
        is at most MAX_LEAD_CELLS; without it the map has none (:attr:`lead`)."""
        goals = tuple(int(g) for g in domain.goals)
        if not goals:
            raise GuideError("guide advice needs the map's destinations: this map has no goal")
        most = MAX_GUIDE_CELLS
        if len(goals) * domain.n_states > most:
            raise GuideError(
                f"guide advice holds a distance per destination and cell: {len(goals)} "
                f"destinations x {domain.n_states} cells is more than {most}"
            )
        s = domain.n_states
        of_state = np.full(s, -1, dtype=np.int64)
        of_state[list(goals)] = np.arange(len(goals))
        takes: Takes = (
            domain.compass_takes
            if isinstance(domain, Building)
            else partial(compass_takes, domain.next_state, domain.cells)
        )
        if searches is not None:
            nearest = domain.nearest_stops if isinstance(domain, Building) else None
            dist, detour, compass = searches(domain.next_state, domain.cells, goals, nearest)
            if dist.shape != (len(goals), s) or detour.shape != (len(goals), s):
                raise ValueError("searches must give (destinations, states) arrays")
            if compass.shape != (s, len(goals)) or compass.dtype != np.uint8:
                raise ValueError("searches must give (states, destinations) compass bytes")
        elif isinstance(domain, Building):
            dist = bfs_distances_each(domain.next_state, goals)
            detour = compass_detours_each(domain.next_state, domain.cells, goals, takes=takes)
        else:
            dist = domain.goal_distances
            detour = compass_detours_each(domain.next_state, domain.cells, goals, takes=takes)
        # a building's floors and stops writeable, as a one-floor map's arrays are (numba
        # compiles read-only arrays anew)
        floor = stops = None
        keep, spread = True, 0
        if isinstance(domain, Building):
            floor = np.require(domain.cells[:, 0], requirements=["C", "W"])
            stops = np.require(domain.nearest_stops, requirements=["C", "W"])
            keep, spread = domain.rides_keep_cells, ride_spread(domain)
        next_state = np.ascontiguousarray(domain.next_state, dtype=np.int64)
        cells = np.ascontiguousarray(domain.cells[:, -2:], dtype=np.int64)  # row, column
        if searches is None:
            compass = compass_table(s, domain.n_actions, goals, takes)
        plain = cls(
            next_state,
            np.ascontiguousarray(domain.open_moves.sum(axis=1), dtype=np.int64),
            cells,
            np.ascontiguousarray(dist, dtype=np.int64),
            np.ascontiguousarray(detour, dtype=np.int64),
            of_state,
            np.zeros((len(goals), s * domain.n_actions)),
            goals,
            landmarks(
                domain.next_state, dist, marks_for(s, n_floors(domain)), distances or _bfs_each
            ),
            np.ascontiguousarray(compass),
            floor,
            stops,
            keep,
            spread,
        )
        if leads is not None and len(goals) * s <= MAX_LEAD_CELLS:
            lead = leads(plain.next_state, plain.n_open, plain.dist)
            if lead.shape != (len(goals), s, 4) or lead.dtype != np.float32:
                raise ValueError("leads must give (destinations, states, 4) float32 values")
            plain = replace(plain, lead=lead)
        return plain if goal_priors is None else plain.replace_counts(goal_priors)

    @property
    def n_states(self) -> int:
        return int(self.next_state.shape[0])

    @property
    def n_goals(self) -> int:
        return len(self.goals)

    @property
    def n_actions(self) -> int:
        return int(self.next_state.shape[1])

    @property
    def arrays(
        self,
    ) -> tuple[
        IntArray, IntArray, IntArray, IntArray, IntArray, FloatArray, IntArray, IntArray,
        IntArray, ByteArray, bool, int, Float32Array,
    ]:  # fmt: skip
        """As app/kernels.py reads it (``GuideArrays``)."""
        floor = _NO_FLOOR if self.floor is None else self.floor
        return (
            self.next_state, self.n_open, self.cells, self.dist, self.goal_of_state, self.counts,
            self.detour, self.marks, floor, self.compass_of, self.cells_bound, self.ride_spread,
            self.lead,
        )  # fmt: skip

    @property
    def goal_states(self) -> IntArray:
        return np.array(self.goals, dtype=np.int64)

    def replace_counts(self, goal_priors: GoalPriors) -> GuideMap:
        """The same map with the experts' counts of ``goal_priors`` (read, not copied, when
        its goals are the map's: a prior update costs no copy per session)."""
        if goal_priors.n_states != self.n_states:
            raise ValueError("the goal priors describe another domain")
        if goal_priors.goals == self.goals:
            counts = goal_priors.goal_counts.reshape(self.n_goals, -1)
        else:
            counts = np.zeros_like(self.counts)
            for i, cell in enumerate(self.goals):
                gi = goal_priors.goal_index.get(cell)
                if gi is not None:
                    counts[i] = goal_priors.goal_counts[gi].reshape(-1)
        return replace(self, counts=counts)

    def policy(self, g: int, s: int) -> list[float]:
        """pi_g(. | s): the shortest moves towards destination g, weighted 1 + expert count."""
        d = int(self.dist[g, s])
        if d > 0:
            n = self.n_actions
            w = [0.0] * n
            tot = 0.0
            for a in range(n):
                if int(self.dist[g, int(self.next_state[s, a])]) == d - 1:
                    w[a] = 1.0 + float(self.counts[g, s * n + a])
                    tot += w[a]
            return [v / tot for v in w]
        return self.open_policy(s)

    def compass_moves(self, g: int, s: int) -> list[int]:
        """The moves of someone at ``s`` heading for destination g as the crow flies (the
        paper's bug): along the axis of the larger row or column difference if that way is
        open, else along the other axis if that way is open and brings it closer; both when
        the differences are equal; none at g or where neither way is open. In a building, on
        another floor than g's, the same towards the nearest stop with a way towards g's
        floor, and at it the ride (``Building.compass_aims``); none where there is no such
        stop."""
        gs = self.goals[g]
        if self.floor is not None and self.stops is not None and self.floor[s] != self.floor[gs]:
            k = 0 if self.floor[gs] > self.floor[s] else 1
            gs = int(self.stops[s, k])
            if gs == s:
                return [4 + k]  # U or D
            if gs < 0:
                return []
        dr = int(self.cells[gs, 0]) - int(self.cells[s, 0])
        dc = int(self.cells[gs, 1]) - int(self.cells[s, 1])
        vert = 0 if dr < 0 else 2
        horiz = 1 if dc > 0 else 3
        v_ok = dr != 0 and int(self.next_state[s, vert]) != s
        h_ok = dc != 0 and int(self.next_state[s, horiz]) != s
        if abs(dr) == abs(dc):
            return [a for a, ok in ((vert, v_ok), (horiz, h_ok)) if ok]
        first, second = ((vert, v_ok), (horiz, h_ok)) if abs(dr) > abs(dc) else (
            (horiz, h_ok), (vert, v_ok))  # fmt: skip
        return [first[0]] if first[1] else ([second[0]] if second[1] else [])

    def compass(self, g: int, s: int) -> list[float]:
        """c_g(. | s): uniform over :meth:`compass_moves`, over the open moves where there is
        none (someone blocked both ways wanders)."""
        moves = self.compass_moves(g, s)
        if not moves:
            return self.open_policy(s)
        return [1.0 / len(moves) if a in moves else 0.0 for a in range(self.n_actions)]

    def compass_route(self, g: int, s: int) -> list[float]:
        """pc_g(. | s): the way to destination g for someone who heads there as the crow
        flies: the open moves after which the fewest moves it would not make by itself remain
        (``detour``), its own moves first; at g, or where g cannot be reached, uniform over
        the open moves."""
        if s == self.goals[g] or int(self.detour[g, s]) < 0:
            return self.open_policy(s)
        own = self.compass_moves(g, s)
        n = self.n_actions
        cost = [-1] * n  # moves it would not make, counting this one
        best = -1
        for a in range(n):
            t = int(self.next_state[s, a])
            if t != s:
                cost[a] = int(self.detour[g, t]) + (0 if a in own else 1)
                if best < 0 or cost[a] < best:
                    best = cost[a]
        pick = [a for a in range(n) if cost[a] == best and a in own]
        if not pick:
            pick = [a for a in range(n) if cost[a] == best]
        return [1.0 / len(pick) if a in pick else 0.0 for a in range(n)]

    def apart(self, u: int, v: int) -> int:
        """A lower bound on the moves from ``u`` to ``v``: the larger of their row plus column
        difference and, over the destinations and the landmarks that both reach, the
        difference of their distances to it. A walk of that many moves between them is a
        shortest path. (In a building whose rides move row or column, the distances only:
        ``cells_bound``.)"""
        far = 0
        if self.cells_bound:
            far = abs(int(self.cells[u, 0]) - int(self.cells[v, 0]))
            far += abs(int(self.cells[u, 1]) - int(self.cells[v, 1]))
        for rows in (self.dist, self.marks):
            for g in range(rows.shape[0]):
                du, dv = int(rows[g, u]), int(rows[g, v])
                if du >= 0 and dv >= 0 and abs(du - dv) > far:
                    far = abs(du - dv)
        return far

    def within(self, u: int, v: int, most: int, budget: int) -> int:
        """Whether a walk of at most ``most`` moves leads from ``u`` to ``v``: 1 if one does, 0
        if none does, -1 if the search gave up (it would queue more than ``budget`` cells, a
        cell once for each way it is reached: up to A x the map's cells, plus one). A
        search from ``u`` that keeps only the cells from which :meth:`apart` leaves ``v`` within
        the moves left (exact: ``apart`` never overestimates), taking first the cells whose
        moves so far plus ``apart`` are fewest (A* with a bucket a number, first in first out
        within one; a cell is taken once); app/kernels.py's ``guide_within`` keeps the same
        order."""
        if u == v:
            return 1 if most >= 0 else 0
        first = self.apart(u, v)
        if first > most:
            return 0
        buckets: list[list[tuple[int, int]]] = [[] for _ in range(most + 1)]
        taken = [0] * (most + 1)
        buckets[first].append((u, 0))
        queued = 1
        done: set[int] = set()
        f = first
        while f <= most:
            if taken[f] == len(buckets[f]):
                f += 1
                continue
            w, d = buckets[f][taken[f]]
            taken[f] += 1
            if w in done:
                continue
            done.add(w)
            for a in range(self.n_actions):
                t = int(self.next_state[w, a])
                if t == w or t in done:
                    continue
                ft = d + 1 + self.apart(t, v)
                if ft > most:
                    continue
                if t == v:
                    return 1
                if queued >= budget:
                    return -1
                buckets[max(ft, f)].append((t, d + 1))
                queued += 1
        return 0

    def floors_apart(self, u: int, v: int) -> int:
        """The floors between ``u`` and ``v`` (0 on one floor)."""
        return 0 if self.floor is None else abs(int(self.floor[u]) - int(self.floor[v]))

    def drift(self, t: int, s: int) -> float:
        """delta_t(s): the mean change of the BFS distance to destination t over the open
        moves of s (0 at t, where t cannot be reached, or with no open move)."""
        here = int(self.dist[t, s])
        if here <= 0:
            return 0.0
        n = 0
        change = 0
        for a in range(self.n_actions):
            u = int(self.next_state[s, a])
            if u != s:
                n += 1
                change += int(self.dist[t, u]) - here
        return change / n if n > 0 else 0.0

    def first_of_tour(self, s: int, alive: list[bool], latency: bool = False) -> int:
        """The destination to lead a lost explorer at ``s`` to first: the first of the
        shortest walk from ``s`` through every destination of ``alive`` it can reach, or with
        ``latency`` of the walk with the least sum of arrivals at them, exact for up to
        ``MAX_TOUR`` of them (by dynamic programming over subsets); beyond, up to
        ``MAX_SEARCHED_TOUR``, the first of the walk with a low sum of arrivals that local
        search finds (:func:`app.domain.tours.searched_order`: as the visitors experiment
        bounds the floor, whatever ``latency``), and beyond that the nearest; -1 if it can
        reach none. Ties go to the lower index."""
        todo = [i for i in range(self.n_goals) if alive[i] and int(self.dist[i, s]) >= 0]
        if not todo:
            return -1
        if len(todo) > MAX_SEARCHED_TOUR:
            return min(todo, key=lambda i: (int(self.dist[i, s]), i))
        if len(todo) > MAX_TOUR:
            start = [int(self.dist[i, s]) for i in todo]
            leg = [[int(self.dist[j, self.goals[i]]) for j in todo] for i in todo]
            return todo[searched_order(start, leg, TOUR_ROUNDS)[0]]
        n = len(todo)
        full = (1 << n) - 1
        inf = 1 << 60
        # rest[mask][j]: the shortest walk from destination todo[j] through the others of
        # mask, or with latency the least sum of arrivals at them (each leg counted once for
        # every destination still ahead)
        rest = [[inf] * n for _ in range(full + 1)]
        for mask in range(1, full + 1):
            for j in range(n):
                if not mask & (1 << j):
                    continue
                others = mask & ~(1 << j)
                if others == 0:
                    rest[mask][j] = 0
                    continue
                here = self.goals[todo[j]]
                best = inf
                for k in range(n):
                    if others & (1 << k):
                        c = (others.bit_count() if latency else 1) * int(self.dist[todo[k], here])
                        c += rest[others][k]
                        if c < best:
                            best = c
                rest[mask][j] = best
        first, first_cost = -1, inf
        for j in range(n):
            c = (n if latency else 1) * int(self.dist[todo[j], s]) + rest[full][j]
            if c < first_cost:
                first, first_cost = todo[j], c
        return first

    def wall(self, s: int, heading: int, hand: int) -> int:
        """The move of a wall follower at ``s`` heading ``heading`` (-1: none yet, then its
        first open way, N E S W): the left hand's (``hand`` 0: left, straight, right, back) or
        the right hand's (1: right, straight, left, back); -1 where every way is shut."""
        turns = (0, 1, 2, 3) if heading < 0 else ((3, 0, 1, 2) if hand == 0 else (1, 0, 3, 2))
        h = max(heading, 0)
        for turn in turns:
            a = (h + turn) % 4
            if int(self.next_state[s, a]) != s:
                return a
        return -1

    def open_policy(self, s: int) -> list[float]:
        """Uniform over the open moves of s (over every action where none is open)."""
        n, k = int(self.n_open[s]), self.n_actions
        if n == 0:
            return [1.0 / k] * k
        return [1.0 / n if int(self.next_state[s, a]) != s else 0.0 for a in range(k)]


@dataclass(frozen=True)
class GuideParams:
    """guide's own parameters: their defaults, bounds and meaning are those of
    :class:`app.advice.params.StrategyParams` (:meth:`of` picks them out)."""

    p_lost: float
    slack: float
    spread: float

    @classmethod
    def of(cls, params: StrategyParams | None = None) -> GuideParams:
        """guide's parameters of ``params`` (None: the defaults)."""
        p = params or StrategyParams()
        return cls(p.p_lost, p.slack, p.spread)


def tour_work(n_goals: int) -> int:
    """The most steps one choice of the next destination (:meth:`GuideMap.first_of_tour`)
    takes on a map of ``n_goals`` destinations, whichever of them are alive: 2^k k^2 for the
    exact tour through k, TOUR_ROUNDS x 4 k^3 for the searched one (k up to
    MAX_SEARCHED_TOUR alive, on a map of more too), the most of these over k <= n_goals."""
    exact = (1 << min(n_goals, MAX_TOUR)) * min(n_goals, MAX_TOUR) ** 2
    if n_goals <= MAX_TOUR:
        return exact
    return max(exact, TOUR_ROUNDS * 4 * min(n_goals, MAX_SEARCHED_TOUR) ** 3)


def kernel_params(
    window: int, p: GuideParams
) -> tuple[
    float, float, float, float, float, int, float, float, float, float, float, int, float, float,
    float, int, int, int, int, int, int, float, float, float, float, int, float, float, float,
    float, int, int,
]:  # fmt: skip
    """The parameters as app/kernels.py reads them: (lam, p_lost, slack, spread, bump,
    MAX_TOUR, COMPLY_FADE, IGNORED, SURE, RELEASE, BACKOFF, COMPLY_LEVELS, CHANCE_MIN,
    CHANCE_MAX, UNDO_RUN, PURPOSE_RUN, PURPOSE_SLACK, PURPOSE_LONG, PURPOSE_LONG_SLACK,
    PURPOSE_WALK, PURPOSE_WALK_PART, ADVICE_RATE, ADVICE_BURST, ADVICE_POWER, PARTLY,
    PURPOSE_SEARCH, DRIFTLESS, ADVICE_KEEP, HEADED, LEAD_PRICE, MAX_SEARCHED_TOUR,
    TOUR_ROUNDS), with lam = 1 - 1/W the evidence's fading."""
    return (
        1.0 - 1.0 / window, float(p.p_lost), float(p.slack), float(p.spread), LOST_BUMP,
        MAX_TOUR, COMPLY_FADE, IGNORED, SURE, RELEASE, float(BACKOFF), COMPLY_LEVELS,
        CHANCE_MIN, CHANCE_MAX, float(UNDO_RUN), PURPOSE_RUN, PURPOSE_SLACK, PURPOSE_LONG,
        PURPOSE_LONG_SLACK, PURPOSE_WALK, PURPOSE_WALK_PART, ADVICE_RATE, ADVICE_BURST,
        ADVICE_POWER, PARTLY, PURPOSE_SEARCH, DRIFTLESS, ADVICE_KEEP, HEADED, LEAD_PRICE,
        MAX_SEARCHED_TOUR, TOUR_ROUNDS,
    )  # fmt: skip


def run_ring(run: list[int]) -> IntArray:
    """``GuideAdvisor._run`` as app/kernels.py keeps it: (how many, the newest's slot, then
    :data:`PURPOSE_WALK` + 1 slots of a ring)."""
    out = np.zeros(PURPOSE_WALK + 3, dtype=np.int64)
    out[0] = len(run)
    out[1] = len(run) - 1 if run else PURPOSE_WALK  # the next one goes to slot 0
    out[2 : 2 + len(run)] = run
    return out


def run_list(ring: IntArray) -> list[int]:
    """The inverse of :func:`run_ring`: the states, oldest first."""
    m, newest, size = int(ring[0]), int(ring[1]), ring.shape[0] - 2
    return [int(ring[2 + (newest - m + 1 + i) % size]) for i in range(m)]


#: where :func:`compliance_state` keeps, after the levels' log-likelihoods: the chance that
#: the explorer's own move is the last decision's advice, the decisions since the last piece,
#: whether advice is held back; the state where the last chain of pieces taken in a row
#: began (-1: none open), how many it took, its own moves since; how many chains in a row
#: its own moves undid (led back to where they began), where the last began (-1: none) and
#: whether it has left that state by its own moves, no piece taken since (1.0) or not (0.0);
#: the last decision's advice (theta's favourite move, given or not; -1: none yet) and whether
#: every move since the last piece was that of the decision before it (1.0: it walks the way
#: it is led) or not (0.0); the pieces of the advice budget saved (:data:`ADVICE_RATE`);
#: where the last piece taken was given (-1: none yet)
CHANCE, SINCE, HELD, CHAIN_FROM, CHAIN_LEN, OWN, UNDONE, UNDONE_AT, AWAY, MODE, ON_LEAD, SAVED = (
    range(COMPLY_LEVELS, COMPLY_LEVELS + 12)
)
PIECE_AT = COMPLY_LEVELS + 12


def compliance_state() -> list[float]:
    """A session's compliance evidence before any advice: a log-likelihood per level, then
    the chance that the explorer's own move is the last decision's advice, the decisions
    since the last piece of advice (:data:`BACKOFF`: none yet), whether advice is held
    back (1.0) or not (0.0), the last chain of pieces taken in a row (where it began, -1:
    none open; its length; the explorer's own moves since), how many chains in a row were
    undone, where the last began (-1: none) and whether the explorer has left it since; no
    decision yet, not led; one piece of the advice budget saved; no piece taken yet."""
    return [
        *[0.0] * COMPLY_LEVELS, 0.5, float(BACKOFF), 0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0, -1.0,
        0.0, 1.0, -1.0,
    ]  # fmt: skip


def upgraded_compliance(comply: list[float]) -> list[float]:
    """A session's compliance evidence as written by an earlier version, without the slots
    of undone advice (``COMPLY_LEVELS + 3`` values), of the way it is led (``+ 9``), of the
    advice budget (``+ 11``) or of where the last piece was taken (``+ 12``), with them as a
    session starts them (none taken, none undone, no decision yet, one piece saved)."""
    full = compliance_state()
    if not COMPLY_LEVELS + 3 <= len(comply) < len(full):
        return comply
    return [*comply, *full[len(comply) :]]


def upgraded_evidence(loglik: list[float], n_goals: int) -> list[float]:
    """A session's evidence per model as written before the lost models LA and LS
    (``N_LOST + 3 G`` sums), with theirs: the open-moves model LO's, the nearest of the lost
    models to them."""
    if len(loglik) != N_LOST + 3 * n_goals:
        return loglik
    return [*loglik, loglik[1], loglik[1]]


def compliance_below(levels: list[float], bound: float) -> float:
    """The posterior probability that the explorer's compliance is below ``bound``, from the
    log-likelihood of each level."""
    n = len(levels)
    mx = levels[0]
    for j in range(1, n):
        if levels[j] > mx:
            mx = levels[j]
    low = 0.0
    tot = 0.0
    for j in range(n):
        w = math.exp(levels[j] - mx)
        if (j + 0.5) / n < bound:
            low += w
        tot += w
    return low / tot


def compliance_mean(levels: list[float]) -> float:
    """The posterior mean of the explorer's compliance (how often it takes advice)."""
    n = len(levels)
    mx = max(levels)
    w = [math.exp(v - mx) for v in levels]
    return sum(wj * (j + 0.5) / n for j, wj in enumerate(w)) / sum(w)


class GuideAdvisor(Advisor):
    """Leads explorers that look lost to a destination of the map; see the module text."""

    strategy = "guide"
    own_advice = True

    __slots__ = (
        "_came", "_comply", "_heading", "_lam", "_last", "_last_advice", "_run", "_target",
        "alive", "doubt", "guide", "p_lost", "slack", "spread",
    )  # fmt: skip

    def __init__(
        self,
        tables: AdviceTables,
        guide: GuideMap,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        *,
        params: GuideParams,
    ):
        if guide.n_states != tables.n_states:
            raise ValueError("guide map and tables describe different domains")
        p = params
        self.guide = guide
        self.p_lost, self.slack, self.spread = float(p.p_lost), float(p.slack), float(p.spread)
        if not (0.0 < self.p_lost < 1.0 and 0.0 < self.slack <= 1.0 and 0 <= self.spread <= 1):
            raise ValueError("need 0 < p_lost < 1, 0 < slack <= 1 and 0 <= spread <= 1")
        super().__init__(tables, kappa, window)
        self._lam = kernel_params(self.window, p)[0]

    def params(self) -> dict[str, int | float]:
        return {"p_lost": self.p_lost, "slack": self.slack, "spread": self.spread}

    def use_tables(self, tables: AdviceTables, goals: GoalPriors | None = None) -> None:
        """New tables; new per-goal counts (more expert trajectories) re-weight the routes."""
        if goals is not None:
            self.guide = self.guide.replace_counts(goals)
        super().use_tables(tables)

    def reset(self) -> None:
        # the paper's window is not kept: guide's evidence is the faded sums below
        self._ring = []
        self._pos = 0
        self.steps = 0
        self.decisions = 0
        self.advice_count = 0
        self.benefit = 0.0
        self._loglik = [0.0] * (N_LOST + 3 * self.guide.n_goals + 2)  # LA's, LS's last
        self.alive = [True] * self.guide.n_goals
        self.doubt = [0] * self.guide.n_goals  # SET_ASIDE, BROUGHT_BACK or 0 (see rule_out)
        self._target = -1
        self._last = -1  # the state the last decision advised (-1: it did not advise)
        n = self.guide.n_actions
        self._last_advice = (1.0 / n,) * n
        self._heading = -1  # the last move that moved (-1: none yet)
        self._came = -1  # where the last move led on the map (-1: no move yet)
        self._comply = compliance_state()
        # where it was decided for since the last piece of advice, oldest first (the last
        # PURPOSE_WALK + 1)
        self._run: list[int] = []

    @property
    def compliance(self) -> float:
        """How often this explorer takes advice, as estimated from its moves after advice."""
        return compliance_mean(self._comply[:COMPLY_LEVELS])

    @property
    def holding_back(self) -> bool:
        """Whether advice is held back: the explorer is taken to ignore it (one piece every
        :data:`BACKOFF` decisions at most)."""
        return self._comply[HELD] != 0.0 or self._comply[UNDONE] >= UNDO_RUN

    @property
    def purposeful(self) -> bool:
        """Whether the explorer walks with a purpose: since the last piece of advice (since
        the first decision while it has had none; after a piece, once it walked
        :data:`PURPOSE_RUN` moves), its last :data:`PURPOSE_RUN` moves were a shortest path
        give or take :data:`PURPOSE_SLACK` moves, its last :data:`PURPOSE_LONG` give or take
        :data:`PURPOSE_LONG_SLACK`, and its last :data:`PURPOSE_WALK` give or take a
        :data:`PURPOSE_WALK_PART`-th of their length, as far as the map's bound can tell
        (:meth:`GuideMap.apart`; the last PURPOSE_RUN and PURPOSE_LONG moves measured where
        it falls short, :meth:`_walked_apart`), with no move into a wall among its last
        :data:`PURPOSE_LONG` (no shortest path has one), and, after advice, neither all the
        way along the way to the target nor each move the advice of the decision before it
        (the way it is led: a visitor walking it is led on). It is then not advised."""
        run = self._run
        if not run or (len(run) <= PURPOSE_RUN and self.advice_count > 0):
            return False
        if any(a == b for a, b in pairwise(run[-1 - PURPOSE_LONG :])):  # it bumped
            return False
        g, n = self.guide, len(run) - 1
        t = self._target
        led = self.advice_count > 0 and n > 0 and t >= 0
        if led and (self._comply[ON_LEAD] != 0.0 or g.dist[t, run[0]] - g.dist[t, run[-1]] == n):
            return False  # after advice, it went the way it is led
        tests = (
            (PURPOSE_RUN, PURPOSE_SLACK),
            (PURPOSE_LONG, PURPOSE_LONG_SLACK),
            (n, max(PURPOSE_LONG_SLACK, n // PURPOSE_WALK_PART)),
        )
        before = 0
        for i, (most, slack) in enumerate(tests):
            k = min(most, n)
            if k <= before:  # the walk of the test before, given more slack
                continue
            before = k
            u, v = run[-1 - k], run[-1]
            # in a building, a quickest walk may take ``ride_spread`` moves more a floor it rides
            low = k - slack - g.floors_apart(u, v) * g.ride_spread
            apart = g.apart(u, v)
            if apart > k or (apart < low and (i == 2 or not self._walked_apart(k, low))):
                return False
        return True

    def _walked_apart(self, k: int, low: int) -> bool:
        """Whether the last ``k`` moves of the run lead at least ``low`` moves apart, measured
        on the walk (a cell it came back to after more than ``k - low`` moves: a walk of
        fewer moves leads there) and then exactly (:meth:`GuideMap.within`, at most
        :data:`PURPOSE_SEARCH` cells; a search given up is no proof)."""
        walk = self._run[-1 - k :]
        first: dict[int, int] = {}
        for j, c in enumerate(walk):
            if j - first.setdefault(c, j) > k - low:
                return False
        return self.guide.within(walk[0], walk[-1], low - 1, PURPOSE_SEARCH) == 0

    @property
    def target(self) -> int:
        """The destination (index) the advice leads to; -1 before the first decision."""
        return self._target

    def append(self, state: int, action: int) -> None:
        """Fade the evidence and add log P(a | s, k) for every model."""
        self._check(state, action)
        g = self.guide
        lam, slack = self._lam, self.slack
        ll = self._loglik
        lo = self._lost_open(state)[action]
        advised = state == self._last
        # LO, LA and LS: their rule, with a bump now and then
        o_lo = self.guide.open_policy(state)[action]
        o_la, o_ls = self._ahead(state)[action], self._straight(state)[action]
        n = g.n_actions
        o_l4 = 1.0 / n
        if advised:  # lost or not, it takes the advice or its own rule, half each (L4 too)
            took = self._last_advice[action]
            o_lo, o_la, o_ls = 0.5 * (o_lo + took), 0.5 * (o_la + took), 0.5 * (o_ls + took)
            o_l4 = 0.5 * (o_l4 + took)
        bump = LOST_BUMP / n
        ll[0] = lam * ll[0] + math.log(o_l4)  # L4: any action, or the advice half the time
        ll[1] = lam * ll[1] + math.log((1.0 - LOST_BUMP) * o_lo + bump)
        ll[-2] = lam * ll[-2] + math.log((1.0 - LOST_BUMP) * o_la + bump)
        ll[-1] = lam * ll[-1] + math.log((1.0 - LOST_BUMP) * o_ls + bump)
        self._observe_compliance(state, advised, action)
        for hand in range(2):
            ind = 1.0 if action == g.wall(state, self._heading, hand) else 0.0
            if advised:
                ind = 0.5 * (ind + self._last_advice[action])
            ll[2 + hand] = lam * ll[2 + hand] + math.log((1.0 - slack) * ind + slack * lo)
        for i in range(g.n_goals):
            pa = g.policy(i, state)[action]
            ca = g.compass(i, state)[action]
            if advised:  # they take the advice or their own way, half each
                pa = 0.5 * (pa + self._last_advice[action])
                ca = 0.5 * (ca + self._last_advice[action])
            k = N_LOST + 3 * i
            ll[k] = lam * ll[k] + math.log((1.0 - slack) * pa + slack / n)
            ll[k + 1] = lam * ll[k + 1] + math.log((1.0 - slack) * pa + slack * lo)
            ll[k + 2] = lam * ll[k + 2] + math.log((1.0 - slack) * ca + slack * lo)
        gi = int(g.goal_of_state[state])
        if gi >= 0 and (self._came < 0 or self._came == state):
            # it stood on this destination and went on: not its destination (a reading that
            # the last move cannot have led to, one cell off, say, rules nothing out)
            self._rule_out(gi)
        self._came = int(g.next_state[state, action])
        if self._came != state and action < N_ACTIONS:  # a heading: a compass move
            self._heading = action
        self.steps += 1

    def _rule_out(self, gi: int) -> None:
        """Destination ``gi`` was stood on and left. At its first visit it is set aside (a
        position read off and walked looks so); seen on it again, or once brought back, it
        is ruled out. Once none is left, those set aside are brought back, once."""
        if self.alive[gi]:
            self.alive[gi] = False
            if self.doubt[gi] == 0:
                self.doubt[gi] = SET_ASIDE
        elif self.doubt[gi] == SET_ASIDE:
            self.doubt[gi] = 0  # seen on it a second time: ruled out
        if not any(self.alive):  # once it passed every one, it is bound elsewhere
            for i, d in enumerate(self.doubt):
                if d == SET_ASIDE:
                    self.alive[i] = True
                    self.doubt[i] = BROUGHT_BACK

    def _observe_compliance(self, state: int, advised: bool, action: int) -> None:
        """After a piece of advice: did the explorer take it? Weighed against the chance
        that its own move was the advised one. And the pieces it took in a row (a chain of
        k): did its own moves after them undo them (lead back to where the chain began
        within k moves, or take back its last piece and take a piece there again)?"""
        comply = self._comply
        took = False  # the advised move, if advice was given
        if advised:
            best = 0
            for a in range(len(self._last_advice)):
                if self._last_advice[a] > self._last_advice[best]:
                    best = a
            took = action == best
        to = int(self.guide.next_state[state, action])
        # on the way it is led: it took the piece, or made the move the advice would have been
        on = took if advised else comply[ON_LEAD] != 0.0 and action == int(comply[MODE])
        comply[ON_LEAD] = 1.0 if on else 0.0
        undid = False
        if took and to != state:  # a piece taken
            if comply[CHAIN_FROM] >= 0.0 and comply[OWN] == 1.0 and state == comply[PIECE_AT]:
                # given where its first own move after the chain took back the chain's last
                # piece: it was undoing the chain, which the piece interrupts
                comply[UNDONE] += 1.0
                comply[UNDONE_AT] = float(state)
                comply[CHAIN_FROM] = -1.0
            comply[PIECE_AT] = float(state)
            if comply[CHAIN_FROM] < 0.0 or comply[OWN] > 0.0:  # the first of a chain
                comply[CHAIN_FROM] = float(state)
                comply[CHAIN_LEN] = 1.0
                comply[OWN] = 0.0
            else:
                comply[CHAIN_LEN] += 1.0
        elif comply[CHAIN_FROM] >= 0.0:  # its own move after a chain: kept, or undone?
            comply[OWN] += 1.0
            if to == int(comply[CHAIN_FROM]):  # back where the chain began: undone
                comply[UNDONE] += 1.0
                comply[UNDONE_AT] = comply[CHAIN_FROM]
                comply[AWAY] = 0.0
                comply[CHAIN_FROM] = -1.0
                undid = True
            elif comply[OWN] >= comply[CHAIN_LEN]:  # as many moves as it took: kept
                comply[UNDONE] = 0.0
                comply[UNDONE_AT] = -1.0
                comply[CHAIN_FROM] = -1.0
        if comply[UNDONE_AT] >= 0.0:  # where it undid the last: does it circle there?
            if took:
                comply[AWAY] = 0.0  # led: no way of its own since
            elif not undid and to != int(comply[UNDONE_AT]):
                comply[AWAY] = 1.0  # its own move away from there
            elif not undid and comply[AWAY] != 0.0:  # and its own moves back there: it
                comply[UNDONE] = 0.0  # circles rather than goes its own way
                comply[UNDONE_AT] = -1.0
                comply[AWAY] = 0.0
        if not advised:
            comply[SINCE] += 1.0
            return
        comply[SINCE] = 1.0
        n = COMPLY_LEVELS
        chance = min(max(comply[CHANCE], CHANCE_MIN), CHANCE_MAX)
        for j in range(n):
            c = (j + 0.5) / n
            lik = c + (1.0 - c) * chance if took else (1.0 - c) * (1.0 - chance)
            comply[j] = COMPLY_FADE * comply[j] + math.log(lik)
        low = compliance_below(comply[:n], IGNORED)
        if low >= SURE:  # it ignores advice: hold it back
            comply[HELD] = 1.0
        elif low < RELEASE:  # it takes advice (again)
            comply[HELD] = 0.0
        # a piece not taken by one that takes only some is given back to the budget
        if not took and compliance_below(comply[:n], PARTLY) >= 0.5:
            comply[SAVED] = min(ADVICE_BURST, comply[SAVED] + 1.0)

    def _lost_open(self, s: int) -> list[float]:
        return self._bumped(self.guide.open_policy(s))

    def _ahead(self, s: int) -> list[float]:
        """LA's rule at ``s``: uniform over the open moves but back (against the heading)
        where another is open and it has moved, over the open moves otherwise."""
        g, h = self.guide, self._heading
        n = int(g.n_open[s])
        if h >= 0 and n > 1 and int(g.next_state[s, (h + 2) % N_ACTIONS]) != s:
            back = (h + 2) % N_ACTIONS
            return [
                1.0 / (n - 1) if a != back and int(g.next_state[s, a]) != s else 0.0
                for a in range(g.n_actions)
            ]
        return g.open_policy(s)

    def _straight(self, s: int) -> list[float]:
        """LS's rule at ``s``: on along the heading where it is open, else LA's."""
        g, h = self.guide, self._heading
        if h >= 0 and int(g.next_state[s, h]) != s:
            return [1.0 if a == h else 0.0 for a in range(g.n_actions)]
        return self._ahead(s)

    def _heading_drift(self, s: int, post: list[float]) -> float:
        """The mean change of the distance to the target of the explorer's own move at ``s``
        as LA and LS (weighted by their shares of ``post``) would make it from its heading."""
        g, t = self.guide, self._target
        here = int(g.dist[t, s])
        if here <= 0:
            return 0.0
        change = [int(g.dist[t, int(g.next_state[s, a])]) - here for a in range(g.n_actions)]
        la, ls = self._ahead(s), self._straight(s)
        ea = sum(p * c for p, c in zip(la, change, strict=True))
        es = sum(p * c for p, c in zip(ls, change, strict=True))
        return (post[-2] * ea + post[-1] * es) / (post[-2] + post[-1])

    def _lead_after(self, s: int, a: int) -> float:
        """The target's lead value (:attr:`GuideMap.lead`) where action ``a`` at ``s`` leaves
        the explorer: its heading ``a`` if it moved by a compass move, else the one it had."""
        u = int(self.guide.next_state[s, a])
        return float(
            self.guide.lead[self._target, u, a if u != s and a < N_ACTIONS else self._heading]
        )

    def _lead_gain(self, s: int, post: list[float], advice: int) -> float:
        """The moves a piece leading by ``advice`` saves at ``s`` as the map's lead values
        reckon them (:attr:`GuideMap.lead`, the target's): the mean over the explorer's own
        move, as LA and LS (weighted by their shares of ``post``) make it from its heading, of
        the value where that move leads, less the value where the advice leads."""
        if int(self.guide.dist[self._target, s]) <= 0:
            return 0.0
        after = partial(self._lead_after, s)
        la, ls = self._ahead(s), self._straight(s)
        ea = sum(p * after(a) for a, p in enumerate(la) if p > 0.0)
        es = sum(p * after(a) for a, p in enumerate(ls) if p > 0.0)
        own = (post[-2] * ea + post[-1] * es) / (post[-2] + post[-1])
        return own - after(advice)

    def _lead_pick(self, s: int, pick: int) -> int:
        """The shortest move towards the target at ``s`` after which the lead value (the
        target's, :attr:`GuideMap.lead`) is least, from the explorer's heading; ``pick`` (r_T)
        where it is as low as any."""
        g, t = self.guide, self._target
        here = int(g.dist[t, s])
        if here <= 0:
            return pick
        low = self._lead_after(s, pick)
        for a in range(g.n_actions):
            u = int(g.next_state[s, a])
            if u != s and int(g.dist[t, u]) == here - 1:
                after = self._lead_after(s, a)
                if after < low:
                    low, pick = after, a
        return pick

    @staticmethod
    def _bumped(o: list[float]) -> list[float]:
        """A lost model's rule ``o`` with LOST_BUMP spread over every action."""
        n = len(o)
        return [(1.0 - LOST_BUMP) * o[a] + LOST_BUMP / n for a in range(n)]

    def _alive(self) -> list[bool]:
        return self.alive if any(self.alive) else [True] * len(self.alive)

    def model_posterior(self) -> list[float]:
        """P(k | H): L4, LO, WL, WR, then D4_g, DO_g, C_g per destination (0 for those ruled
        out), then LA and LS."""
        alive = self._alive()
        n_alive = sum(alive)
        lw_lost = math.log(self.p_lost / (N_LOST + 2.0))
        lw_dir = math.log((1.0 - self.p_lost) / (3.0 * n_alive))
        ll = self._loglik
        z = [ll[k] + lw_lost for k in range(N_LOST)]
        for i, on in enumerate(alive):
            for j in range(3):
                z.append(ll[N_LOST + 3 * i + j] + lw_dir if on else -math.inf)
        z.append(ll[-2] + lw_lost)
        z.append(ll[-1] + lw_lost)
        mx = max(z)
        e = [0.0 if v == -math.inf else (1.0 if v == mx else math.exp(v - mx)) for v in z]
        tot = 0.0
        for v in e:
            tot += v
        return [v / tot for v in e]

    def goal_beliefs(self) -> list[tuple[int, float, bool]]:
        """(destination, P(g | H) + P(lost | H) / n_alive, ruled out) per destination."""
        post = self.model_posterior()
        alive = self._alive()
        n_alive = sum(alive)
        lost = post[0] + post[1] + post[2] + post[3] + post[-2] + post[-1]
        return [
            (cell, self._p_goal(post, i) + lost / n_alive if alive[i] else 0.0, not self.alive[i])
            for i, cell in enumerate(self.guide.goals)
        ]

    @staticmethod
    def _p_goal(post: list[float], i: int) -> float:
        k = N_LOST + 3 * i
        return post[k] + post[k + 1] + post[k + 2]

    def decide(self, state: int) -> Decision:
        self._check(state)
        g = self.guide
        post = self.model_posterior()
        alive = self._alive()
        lost = post[0] + post[1] + post[2] + post[3] + post[-2] + post[-1]
        pis = [g.policy(i, state) if alive[i] else None for i in range(g.n_goals)]
        cs = [g.compass(i, state) if alive[i] else None for i in range(g.n_goals)]
        pcs = [g.compass_route(i, state) if alive[i] else None for i in range(g.n_goals)]
        # the target: the first destination of the best walk through those not ruled out
        # (the least sum of arrivals for a walker without drift), planned again once it is
        # ruled out
        driftless = post[0] + post[1] >= DRIFTLESS  # a lost walker with no drift of its own
        headed = not driftless and post[-2] + post[-1] >= HEADED  # one that keeps a heading
        # the lead values decide for it: they are the walk of one that never turns back (LA),
        # so for one taken rather for it than for one that goes straight on (LS)
        by_lead = headed and post[-2] >= post[-1] and g.lead.shape[0] > 0 and self._heading >= 0
        if self._target < 0 or not alive[self._target]:
            self._target = g.first_of_tour(state, alive, driftless)
        pi_t = g.open_policy(state)
        target_pi = pis[self._target] if self._target >= 0 else None
        n = g.n_actions
        pick = -1
        if target_pi is not None:  # r_T: one shortest move (the heaviest; the heading on a tie)
            for a in range(n):
                if (
                    pick < 0
                    or target_pi[a] > target_pi[pick]
                    or (target_pi[a] == target_pi[pick] and a == self._heading)
                ):
                    pick = a
            if by_lead:
                pick = self._lead_pick(state, pick)  # along its way: the lead values' least
            pi_t = [1.0 if a == pick else 0.0 for a in range(n)]
        lo = self._lost_open(state)
        la, ls = self._bumped(self._ahead(state)), self._bumped(self._straight(state))
        wl, wr = g.wall(state, self._heading, 0), g.wall(state, self._heading, 1)
        slack, spread = self.slack, self.spread
        theta = [0.0] * n
        chance = [0.0] * n  # P(A | s, H): what the explorer does by itself
        kl = 0.0
        for a in range(n):
            v = lost * pi_t[a]
            m = post[0] * (1.0 / n) + post[1] * lo[a]
            m += post[2] * ((1.0 - slack) * (1.0 if a == wl else 0.0) + slack * lo[a])
            m += post[3] * ((1.0 - slack) * (1.0 if a == wr else 0.0) + slack * lo[a])
            m += post[-2] * la[a]
            m += post[-1] * ls[a]
            for i in range(g.n_goals):
                pi, c, pc = pis[i], cs[i], pcs[i]
                if pi is not None and c is not None and pc is not None:
                    k = N_LOST + 3 * i
                    v += (post[k] + post[k + 1]) * pi[a] + post[k + 2] * pc[a]
                    m += post[k] * ((1.0 - slack) * pi[a] + slack / n)
                    m += post[k + 1] * ((1.0 - slack) * pi[a] + slack * lo[a])
                    m += post[k + 2] * ((1.0 - slack) * c[a] + slack * lo[a])
            th = (1.0 - spread) * v + spread / n
            theta[a] = th
            chance[a] = m
            if th > 0.0:
                kl += th * (math.log(th) - math.log(m))
        loses_ground = False
        if self._target >= 0:  # the value: weighted by what a lost explorer's move costs here
            d = g.drift(self._target, state)  # over the open moves; L4's over every action
            kl = kl * (1.0 + (lost - post[0]) * d + post[0] * (d * int(g.n_open[state]) / n))
            loses_ground = d > 0.0  # its own move, on average
            # over its way where it takes what it is given (the values' leads are taken)
            whole = compliance_below(self._comply[:COMPLY_LEVELS], PARTLY) < 0.5
            if by_lead and whole and pick >= 0:
                # its own way from its heading, as LA and LS would make it, against the lead's
                loses_ground = self._lead_gain(state, post, pick) > LEAD_PRICE
            elif headed:  # its own move from its heading, as LA and LS would make it
                loses_ground = self._heading_drift(state, post) > 0.0
        kl = kl if kl > 0.0 else 0.0
        if n != 4:  # in four actions' units, as the paper's rule's (AdviceTables.kl_scale)
            kl = kl * kl_scale(n)
        best = 0  # the advice: theta's favourite move
        for a in range(n):
            if theta[a] > theta[best]:
                best = a
        self._comply[CHANCE] = chance[best]  # its own move would be the advice this often
        self._comply[MODE] = float(best)
        for a in range(n):
            theta[a] = (1.0 - spread) * (1.0 if a == best else 0.0) + spread / n
        row = tuple(theta)
        # an explorer that ignores advice is left in peace, but for a piece now and then
        allowed = not self.holding_back or self._comply[SINCE] >= BACKOFF
        allowed = allowed and any(self.alive)  # none left: it is bound elsewhere
        self._run.append(state)
        if len(self._run) > PURPOSE_WALK + 1:
            del self._run[0]
        allowed = allowed and not self.purposeful  # it walks a way of its own
        # the advice budget: a piece more saved each 1 / ADVICE_RATE decisions, the value
        # divided by the price of the pieces saved
        saved = min(ADVICE_BURST, self._comply[SAVED] + ADVICE_RATE)
        self._comply[SAVED] = saved
        ruled = post[2] + post[3]  # one with a rule of its own: a hand on the wall, the compass
        for i in range(g.n_goals):
            ruled += post[N_LOST + 3 * i + 2]
        free = ruled >= 0.5  # its detours are not held to the budget (paid for afterwards)
        if saved >= 1.0 and not free:
            if (driftless or headed) and saved < ADVICE_BURST:  # where it loses ground, no price
                if not (loses_ground and saved >= 1.0 + ADVICE_KEEP):
                    kl = 0.0
            else:
                kl = kl / (ADVICE_BURST / saved) ** ADVICE_POWER
        allowed = allowed and (saved >= 1.0 or free)
        advise = kl >= self.kappa and self.advice_count < self.cap and allowed
        self._last = state if advise else -1
        if advise:
            self._comply[SAVED] = saved - 1.0
            self._last_advice = row
            self._run = [state]
        return self.record(state, advise, row, kl, 1.0 - lost)
