"""The session registry's bounded history."""

from __future__ import annotations

from collections import deque

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from app.service.registry import Recent


@given(
    size=st.integers(1, 20),
    first=st.integers(0, 1000),
    batches=st.lists(st.lists(st.integers(0, 1000), max_size=45), max_size=10),
)
def test_recent_keeps_what_a_bounded_deque_keeps(
    size: int, first: int, batches: list[list[int]]
) -> None:
    ring, reference = Recent(size, np.int32, first), deque([first], maxlen=size)
    for batch in batches:
        ring.extend(batch)
        reference.extend(batch)
        assert ring.tolist() == list(reference)
