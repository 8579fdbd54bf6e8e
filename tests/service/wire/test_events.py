"""Events to (s, a, s'): the checks against a slow, obviously correct version, and the
one-event path against the batch path (the same moves and the same words)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from app.domain.grid import ACTIONS, GridDomain
from app.service.problems import BadInput, describe_errors
from app.service.wire.events import read_move, read_moves
from tests.service.conftest import TINY

DOMAIN = GridDomain.from_strings(TINY)
ROWS, COLS = DOMAIN.shape


def slow_moves(events: list[dict[str, Any]]) -> list[tuple[int, int, int]] | int:
    """The spec, one event at a time: the moves, or the index of the first bad event."""
    out = []
    for i, e in enumerate(events):
        try:
            s = DOMAIN.state(*e["state"])
            nxt = e.get("next_state")
            s2 = None if nxt is None else DOMAIN.state(*nxt)
        except ValueError:
            return i
        a = e.get("action")
        a = None if a is None else (ACTIONS.index(a) if isinstance(a, str) else a)
        if a is None and s2 is None:
            return i
        if s2 is None:
            s2 = DOMAIN.step(s, a)  # type: ignore[arg-type]
        elif s2 != s and DOMAIN.move_between(s, s2) is None:
            return i  # not one move away
        if a is None:
            a = DOMAIN.move_between(s, s2)
            if a is None:  # unchanged cell, no action: ambiguous
                return i
        out.append((s, a, s2))
    return out


cells = st.tuples(st.integers(0, ROWS), st.integers(0, COLS))  # includes off-map and walls
events = st.fixed_dictionaries(
    {"state": cells},
    optional={
        "action": st.one_of(st.none(), st.sampled_from([*ACTIONS, 0, 1, 2, 3])),
        "next_state": st.one_of(st.none(), cells),
    },
)


def moves(raw: str, limit: int = 100) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return read_moves(DOMAIN, raw, limit)[0]


@given(st.lists(events, max_size=30), st.booleans())
def test_read_moves_matches_slow_version(batch: list[dict[str, Any]], spaced: bool) -> None:
    """Written plainly (the compiled reader) or with other spacing: the same checks."""
    expected = slow_moves(batch)
    raw = json.dumps(batch, indent=1 if spaced else None)
    if isinstance(expected, int):
        with pytest.raises(BadInput) as err:
            moves(raw, 1000)
        assert err.value.detail.startswith(f"event {expected}:")
        assert err.value.status == 422
    else:
        s, a, s2 = moves(raw, 1000)
        assert list(zip(s.tolist(), a.tolist(), s2.tolist(), strict=True)) == expected


@given(st.lists(st.tuples(st.sampled_from(range(DOMAIN.n_states)), st.integers(0, 3)), max_size=20))
def test_the_three_event_forms_give_the_same_moves(pairs: list[tuple[int, int]]) -> None:
    with_action = [{"state": DOMAIN.cell(s), "action": ACTIONS[a]} for s, a in pairs]
    both = [
        e | {"next_state": DOMAIN.cell(DOMAIN.step(s, a))}
        for e, (s, a) in zip(with_action, pairs, strict=True)
    ]
    moved = [(s, a) for s, a in pairs if DOMAIN.step(s, a) != s]
    only_next = [
        {"state": DOMAIN.cell(s), "next_state": DOMAIN.cell(DOMAIN.step(s, a))} for s, a in moved
    ]
    a1 = np.stack(moves(json.dumps(with_action)))
    a2 = np.stack(moves(json.dumps(both)))
    a3 = np.stack(moves(json.dumps(only_next)))
    np.testing.assert_array_equal(a1, a2)
    keep = np.array([DOMAIN.step(s, a) != s for s, a in pairs], dtype=bool)
    np.testing.assert_array_equal(a1[:, keep] if pairs else a1, a3)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ('{"state": [5, 1]}', "event 0: give an action, a next_state or both"),
        ('{"state": [0, 0], "action": "N"}', "event 0: state [0, 0] is a wall"),
        ('{"state": [9, 1], "action": "N"}', "event 0: state [9, 1] is off the 7x7 map"),
        ('{"state": [5, 1], "next_state": [5, 1]}', "ambiguous"),
        ('{"state": [5, 1], "next_state": [5, 3]}', "is not one move from state [5, 1]"),
        ('{"state": [5, 1], "action": "E", "next_state": [0, 0]}', "next_state [0, 0] is a wall"),
        ('{"state": [5, 1], "action": "up"}', "event.action: an action is 'N', 'E', 'S', 'W'"),
        ('{"state": [5, 1], "action": true}', "event.action: an action is"),
        ('{"state": [5, 1], "action": 1.0}', "event.action: an action is"),
        ('{"state": [5, 1], "action": 6}', "event.action: an action is"),
        ('{"state": [5, 1], "action": 4}', "event 0: action 'U' changes floor"),
        ('[{"state": [5, 1], "action": "D"}]', "event 0: action 'D' changes floor"),
        ('{"state": [0, 5, 1], "action": "N"}', "this map has one floor: a cell is [row, col]"),
        ('{"state": ["5", 1], "action": "N"}', "event.state[0]: Input should be a valid integer"),
        ('{"state": [-1, 1], "action": "N"}', "event.state[0]: Input should be greater than"),
        ('{"state": [5, 1], "action": "N", "why": 1}', "event.why: Extra inputs are not permitted"),
        ('[{"state": [5, 1], "action": "N"}, {"state": [5]}]', "events[1].state"),
        ('{"state": [5, 1], "action": "N"', "Invalid JSON"),
        ('"N"', "send JSON: an event"),
        ("", "send JSON: an event"),
        ("[" * 10_000 + "]" * 10_000, "recursion limit"),
    ],
)
def test_bad_events_are_refused_with_a_reason(body: str, message: str) -> None:
    with pytest.raises(BadInput) as err:  # the batch path (lists, binary answers)
        moves(body)
    assert err.value.status == 422
    assert message in err.value.detail
    if body.lstrip().startswith("{"):  # the one-event path gives the same words
        with pytest.raises(BadInput) as one:
            read_move(DOMAIN, body)
        assert (one.value.status, one.value.detail) == (422, err.value.detail)


def test_unchanged_cell_with_action_is_a_bump() -> None:
    s, a, s2 = moves('{"state": [5, 1], "action": "W"}')
    assert (s[0], a[0], s2[0]) == (DOMAIN.state(5, 1), 3, DOMAIN.state(5, 1))


def test_an_observed_move_other_than_the_action_is_accepted() -> None:
    # a slippery world: the explorer meant N (a wall) but slid E
    body = '{"state": [5, 1], "action": "N", "next_state": [5, 2]}'
    _, a, s2 = moves(body)
    assert (a[0], s2[0]) == (0, DOMAIN.state(5, 2))


def test_too_many_events_is_413() -> None:
    with pytest.raises(BadInput) as err:
        moves(json.dumps([{"state": [5, 1], "action": "N"}] * 11), 10)
    assert err.value.status == 413
    assert "at most 10" in err.value.detail


def test_describe_errors_names_place_and_problem_and_counts_the_rest() -> None:
    errors = [{"loc": ("body", "items", i, "x"), "msg": "bad"} for i in range(8)]
    text = describe_errors(errors, limit=2)
    assert text == "body.items[0].x: bad; body.items[1].x: bad (and 6 more)"


def _single(raw: str | bytes) -> Any:
    """read_move's answer: the move, or the refusal."""
    try:
        return read_move(DOMAIN, raw)
    except BadInput as exc:
        return ("refused", exc.status, exc.detail)


def _parsed(raw: str | bytes) -> Any:
    """The full parser's answer for one event object, through the batch path."""
    try:
        checked, single, first = read_moves(DOMAIN, raw, 1)
        assert single
        return (*(int(x[0]) for x in checked), -1 if first is None else first)
    except BadInput as exc:
        return ("refused", exc.status, exc.detail)


single_texts = st.builds(
    lambda r, c, a, step, sep, pad, as_bytes: (lambda t: t.encode() if as_bytes else t)(
        pad
        + json.dumps(
            {"state": [r, c], "action": a} | ({} if step is None else {"step": step}),
            separators=sep,
        )
        + pad
    ),
    st.integers(0, ROWS + 1)
    | st.sampled_from([999_999_999, 1_000_000_000, 2**31 - 1, 2**31, 10**12])
    | st.integers(0, 2**31 + 5),
    st.integers(0, COLS + 1),
    st.sampled_from(ACTIONS),
    st.none() | st.integers(-1, 12) | st.sampled_from([999_999_999, 10**9, 2**31, 2**53]),
    st.sampled_from([(",", ":"), (", ", ": "), (",", ": "), (", ", ":")]),
    st.sampled_from(["", " ", "\n", "\t ", "\r\n"]),
    st.booleans(),
)


@given(single_texts, st.data())
def test_one_event_is_read_as_the_parser_reads_it(raw: str | bytes, data: Any) -> None:
    """read_move (the single-event path: plain ints, no arrays) against the batch path, on
    texts of one event (cells on and off the map, walls) and on mutated ones."""
    assert _single(raw) == _parsed(raw)
    text = raw.decode() if isinstance(raw, bytes) else raw
    for at, piece in data.draw(st.lists(st.tuples(st.integers(0, len(text)), st.sampled_from(
        ['"', ",", ":", "[", "]", "{", "}", " ", "\f", "-", ".", "e", "0", "00", "7", "x",
         "null", '"N"', '"step"', "\u00e9", "1e3", "99999999999", ""]
    )), max_size=2)):  # fmt: skip
        text = text[:at] + piece + text[at + data.draw(st.integers(0, 2)) :]
    mutated = text.encode() if isinstance(raw, bytes) else text
    if mutated.lstrip()[:1] in (b"{", "{"):
        assert _single(mutated) == _parsed(mutated)


@pytest.mark.parametrize(
    "raw",
    [
        '{"state":[05,1],"action":"E"}',
        '{"state":[5,01],"action":"E"}',
        '{"state":[999999999,1],"action":"E"}',
        '{"state":[2147483648,1],"action":"E"}',
        '{"state":[1000000000,1],"action":"E"}',
        '{"state":[5,2147483648],"action":"E"}',
        '{"state":[5,1],"action":"e"}',
        '{"state":[5,1],"action":"n"}',
        '\f{"state":[5,1],"action":"E"}',
        '{"state":[5,1],"action":"E"}\v',
        '{"state":[5,1],"action":"E"}\r\n',
        '{"state":  [5,1],"action":"E"}',
        '{"state":[5,1],"action":"E","action":"W"}',
        '{"state":[5,1],"action":"E"} {}',
        '{"state":[1,0],"action":"E"}',
        '{"state":[30,1],"action":"E"}',
        '{"state":[5,1],"action":"E","step":1}',
        '{"state":[5,1],"action":"E", "step": 999999999}',
        '{"state":[5,1],"action":"E","step":0}',
        '{"state":[5,1],"action":"E","step":01}',
        '{"state":[5,1],"action":"E","step":-3}',
        '{"state":[5,1],"action":"E","step":1.0}',
        '{"state":[5,1],"action":"E","step":"1"}',
        '{"state":[5,1],"action":"E","step":1,"step":2}',
        '{"step":3,"state":[5,1],"action":"E"}',
    ],
)
def test_one_event_edge_cases_are_read_as_the_parser_reads_them(raw: str) -> None:
    assert _single(raw) == _parsed(raw)
    assert _single(raw.encode()) == _parsed(raw.encode())
