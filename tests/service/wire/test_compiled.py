"""The compiled reader of plain event lists (app/service/wire/compiled.py) against the full
parser: ``read_moves`` must give what it gives with pydantic alone, moves or error, for any
text; the reader may only decline (and let the full parser answer)."""

from __future__ import annotations

import json
from typing import Any
from unittest import mock

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from app.domain.grid import ACTIONS, GridDomain
from app.service.problems import BadInput
from app.service.wire import events as wire_events
from app.service.wire.compiled import scan_events
from app.service.wire.events import read_moves
from tests.service.conftest import TINY

DOMAIN = GridDomain.from_strings(TINY)
ROWS, COLS = DOMAIN.shape

cells = st.lists(st.integers(0, ROWS), min_size=2, max_size=2)  # includes off-map and walls
events = st.fixed_dictionaries(
    {"state": cells},
    optional={
        "action": st.one_of(st.none(), st.sampled_from([*ACTIONS, 0, 1, 2, 3])),
        "next_state": st.one_of(st.none(), cells),
        "step": st.one_of(st.integers(-2, 3), st.integers(1, 2**33)),  # mostly out of turn
    },
)
layouts = st.sampled_from([(None, (",", ":")), (None, (", ", ": ")), (1, None), (" \t", None)])


def outcome(fn: Any, raw: str | bytes) -> Any:
    try:
        moves, single, first = fn(raw)
    except BadInput as exc:
        return ("refused", exc.status, exc.detail)
    return ([a.tolist() for a in moves], single, first)


def slow(raw: str | bytes, limit: int = 100) -> Any:
    """``read_moves`` with the compiled reader declining everything: pydantic reads."""
    with mock.patch.object(wire_events, "scan_events", lambda _: None):
        return read_moves(DOMAIN, raw, limit)


def fast(raw: str | bytes, limit: int = 100) -> Any:
    return read_moves(DOMAIN, raw, limit)


@given(st.lists(events, max_size=40), layouts, st.booleans())
def test_read_moves_equals_the_full_parser(
    batch: list[dict[str, Any]], layout: tuple[Any, Any], as_bytes: bool
) -> None:
    indent, separators = layout
    text = json.dumps(batch, indent=indent, separators=separators)
    raw: str | bytes = text.encode() if as_bytes else text
    assert outcome(fast, raw) == outcome(slow, raw)


@given(
    st.lists(events, min_size=1, max_size=30),
    st.data(),
)
def test_mutated_texts_get_the_same_answer(batch: list[dict[str, Any]], data: Any) -> None:
    text = json.dumps(batch)
    edits = data.draw(st.lists(st.tuples(st.integers(0, len(text)), st.sampled_from(
        ['"', ",", ":", "[", "]", "{", "}", " ", "-", ".", "e", "0", "7", "null", "true",
         '"x"', '"state"', '"action"', '"step"', "\\u0041", "\u00e9", "1e3", "00",
         "99999999999", ""]
    )), max_size=3))  # fmt: skip
    for at, piece in edits:
        cut = data.draw(st.integers(0, 2))
        text = text[:at] + piece + text[at + cut :]
    assert outcome(fast, text) == outcome(slow, text)


def test_the_reader_declines_what_it_does_not_read_plainly() -> None:
    for n in (1, 2, 9):
        assert scan_events(json.dumps([{"state": [5, 1], "action": "E"}] * n)) is not None
    declined = [
        '[{"state": [5, 1.0], "action": "E"}]',
        '[{"state": [5, 1], "action": "E", "action": "E"}]',
        '[{"state": [5, 1], "action": "\\u0045"}]',
        '[{"st\\u0061te": [5, 1], "action": "E"}]',
        '[{"state": [5, 1], "action": "E", "why": 1}]',
        '[{"state": [5, -1], "action": "E"}]',
        '[{"state": [5, 01], "action": "E"}]',
        '[{"state": [5, 2147483648], "action": "E"}]',
        '[{"state": [5, 1], "action": 4}]',
        '[{"state": [5, 1], "action": 1e0}]',
        '[{"state": [5, 1], "action": true}]',
        '[{"action": "E"}]',
        '[{"state": [5, 1, 2], "action": "E"}]',
        '[{"state": null, "action": "E"}]',
        '[{"state": [5, 1], "action": "E"},]',
        '[{"state": [5, 1], "action": "E"}] x',
        '{"state": [5, 1], "action": "E"}',
        "[]",
    ]
    for text in declined:
        assert scan_events(text) is None, text
        assert outcome(fast, text) == outcome(slow, text), text


def test_a_large_plain_batch_is_read_by_the_compiled_reader() -> None:
    rng = np.random.default_rng(0)
    s, batch = DOMAIN.start, []
    for a in rng.integers(0, 4, 500).tolist():
        batch.append({"state": list(DOMAIN.cell(s)), "action": ACTIONS[a]})
        s = DOMAIN.step(s, a)
    text = json.dumps(batch)
    scanned = scan_events(text)
    assert scanned is not None and len(scanned[0]) == 500
    moves = outcome(lambda raw: fast(raw, 500), text)
    assert moves[0] != "refused"
    assert moves == outcome(lambda raw: slow(raw, 500), text)
    too_many = outcome(lambda raw: fast(raw, 499), text)
    assert too_many == ("refused", 413, "too many events: 500 in one batch, at most 499")


@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 300),
    layout=st.sampled_from([(None, (",", ":")), (None, None), (1, None)]),
    with_next=st.floats(0, 1),
)
def test_walks_are_read_as_the_full_parser_reads_them(
    seed: int, n: int, layout: tuple[int | None, tuple[str, str] | None], with_next: float
) -> None:
    """Valid batches (random walks, some events with a next_state), in the layouts clients
    write: the compiled reader's moves, its fast path for the common event included, are the
    full parser's."""
    rng = np.random.default_rng(seed)
    s, batch = DOMAIN.start, []
    for a in rng.integers(0, 4, n).tolist():
        s2 = DOMAIN.step(s, a)
        event: dict[str, Any] = {"state": list(DOMAIN.cell(s)), "action": ACTIONS[a]}
        if rng.random() < with_next:
            event["next_state"] = list(DOMAIN.cell(s2))
        batch.append(event)
        s = s2
    indent, separators = layout
    text = json.dumps(batch, indent=indent, separators=separators)
    assert scan_events(text) is not None
    got = outcome(lambda raw: fast(raw, 300), text)
    assert got == outcome(lambda raw: slow(raw, 300), text)


@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 200),
    first=st.integers(1, 2**31 - 300),
    numbered=st.floats(0, 1),
    layout=st.sampled_from([(None, (",", ":")), (None, None), (1, None)]),
)
def test_numbered_walks_are_read_by_the_compiled_reader(
    seed: int, n: int, first: int, numbered: float, layout: tuple[Any, Any]
) -> None:
    """A client that retries numbers its events (``"step"``): the compiled reader reads such
    batches itself, some events numbered and some not, and finds their first step as the
    full parser does."""
    rng = np.random.default_rng(seed)
    s, batch = DOMAIN.start, []
    for i, a in enumerate(rng.integers(0, 4, n).tolist()):
        event: dict[str, Any] = {"state": list(DOMAIN.cell(s)), "action": ACTIONS[a]}
        if rng.random() < numbered:
            event["step"] = first + i
        batch.append(event)
        s = DOMAIN.step(s, a)
    indent, separators = layout
    text = json.dumps(batch, indent=indent, separators=separators)
    assert scan_events(text) is not None
    got = outcome(lambda raw: fast(raw, 200), text)
    assert got == outcome(lambda raw: slow(raw, 200), text)
    numbered_any = any("step" in e for e in batch)
    assert got[2] == (first if numbered_any else None)


def test_steps_out_of_their_batch_numbering_are_refused_naming_the_event() -> None:
    text = json.dumps([
        {"state": [5, 1], "action": "E", "step": 4},
        {"state": [5, 2], "action": "W"},
        {"state": [5, 1], "action": "E", "step": 7},
    ])  # fmt: skip
    assert outcome(fast, text) == outcome(slow, text)
    status, detail = outcome(fast, text)[1:]
    assert status == 422 and detail.startswith("event 2: step 7 does not follow"), detail
    zero_base = json.dumps(
        [{"state": [5, 1], "action": "E"}, {"state": [5, 2], "action": "W", "step": 1}]
    )
    assert outcome(fast, zero_base)[2].startswith("event 1: step 1 does not follow")
