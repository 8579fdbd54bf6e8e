"""Shared test settings: hypothesis profiles (CI runs the same examples every time)."""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from app.domain.generate import generate_maze

settings.register_profile(
    "default", max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile(
    "ci",
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("ci" if os.environ.get("CI") else "default")


@pytest.fixture(scope="session")
def small_maze(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A map file for the experiments: any valid map works, so a generated 11x11 maze with 3
    goals, not the shipped one."""
    path = tmp_path_factory.mktemp("maze") / "small.txt"
    rows = generate_maze(11, 11, np.random.default_rng(4), braid=0.3, n_goals=3)
    path.write_text("\n".join(rows) + "\n")
    return path


@functools.cache
def service_kernels_compiled() -> None:
    """Compile (or load from numba's cache) what a service compiles as it starts
    (:func:`app.service.wire.loops.warm_up`), once in this test process, before a test starts a
    server: the server then loads it from the cache (``app/__pycache__``), and the time it is
    given to answer ``/health`` is its own start's, not a cold cache's compile (40 s alone,
    over 60 s with the other test process and a busy machine, from a fresh clone)."""
    from app.service.wire.loops import warm_up

    warm_up()
