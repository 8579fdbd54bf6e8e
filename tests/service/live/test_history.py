"""A session's bounded history: the rings of its recent path, posterior and advice."""

from __future__ import annotations

from collections import deque

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from app.advice.models import AdviceTables
from app.service.live.history import AdviceLog, Recent


@given(
    size=st.integers(1, 20),
    first=st.integers(0, 1000),
    batches=st.lists(
        st.tuples(st.lists(st.integers(0, 1000), max_size=45), st.booleans()), max_size=10
    ),
)
def test_recent_keeps_what_a_bounded_deque_keeps(
    size: int, first: int, batches: list[tuple[list[int], bool]]
) -> None:
    """Numbers pushed in batches, or one at a time (``push``, the single-event path)."""
    ring, reference = Recent(size, np.int32, first), deque([first], maxlen=size)
    for batch, one_by_one in batches:
        if one_by_one:
            for value in batch:
                ring.push(value)
        else:
            ring.extend(batch)
        reference.extend(batch)
        assert ring.tolist() == list(reference)


TABLES = [AdviceTables.paper(np.full((2, 4), 0.25)) for _ in range(6)]


@given(
    size=st.integers(1, 12),
    batches=st.lists(
        st.tuples(st.lists(st.integers(0, 10**6), max_size=30), st.integers(0, 5), st.booleans()),
        max_size=12,
    ),
)
def test_advice_log_keeps_what_a_bounded_deque_keeps(
    size: int, batches: list[tuple[list[int], int, bool]]
) -> None:
    """Advice logged in batches, or one at a time (``add``, the single-event path)."""
    log = AdviceLog(size)
    reference: deque[tuple[int, int, AdviceTables]] = deque(maxlen=size)
    for steps, which, one_by_one in batches:
        states = [s % 97 for s in steps]
        if one_by_one:
            for a, s in zip(steps, states, strict=True):
                log.add(a, s, TABLES[which], None)
        else:
            log.extend(
                np.array(steps, dtype=np.int64), np.array(states, dtype=np.int64), TABLES[which]
            )
        reference.extend((a, s, TABLES[which]) for a, s in zip(steps, states, strict=True))
        got = log.items()
        assert [(a, s) for a, s, _ in got] == [(a, s) for a, s, _ in reference]
        assert all(t is r for (_, _, t), (_, _, r) in zip(got, reference, strict=True))
        # tables no entry refers to are let go (each kept one has an entry, but the newest)
        assert len(log._tables) <= max(size + 1, 4)


@given(
    size=st.integers(1, 12),
    seed=st.integers(0, 2**32 - 1),
    ops=st.lists(
        st.tuples(
            st.sampled_from(["one", "batch", "tables", "forget", "written"]),
            st.integers(1, 30),
            st.booleans(),
        ),
        max_size=25,
    ),
)
def test_an_advice_log_written_out_reads_back_as_it_was(
    size: int, seed: int, ops: list[tuple[str, int, bool]]
) -> None:
    """Entries added one at a time and in batches, under changing tables, with the advisor's
    own advice or theta_s, some forgotten: what ``written`` gives, read back, lists what
    ``items`` lists, whenever it is asked (its cache of written-out rows included)."""
    rng = np.random.default_rng(seed)

    def tables() -> AdviceTables:
        return AdviceTables.paper(rng.dirichlet(np.ones(4), 20))

    log, t, step, when = AdviceLog(size), tables(), 0, 0
    for op, n, own in ops:
        if op == "tables":
            t = tables()
        elif op == "forget":
            log.forget_before(when - n)
        elif op == "one":
            step, when = step + 1, when + 1
            a, b, c, d = rng.dirichlet(np.ones(4)).tolist()
            log.add(step, int(rng.integers(20)), t, (a, b, c, d) if own else None, when)
        elif op == "batch":
            steps = np.arange(step + 1, step + n + 1)
            step, when = step + n, when + 1
            rows = rng.dirichlet(np.ones(4), n) if own else None
            log.extend(steps, rng.integers(0, 20, n), t, rows, when)
        want = [(a, s, _row(src, s)) for a, s, src in log.items()]
        back = AdviceLog.read(size, log.written(), t)
        assert [(a, s, _row(src, s)) for a, s, src in back.items()] == want


def _row(src: object, state: int) -> list[float]:
    if isinstance(src, AdviceTables):
        out: list[float] = src.theta[state].tolist()
        return out
    assert isinstance(src, tuple)
    return [float(x) for x in src]
