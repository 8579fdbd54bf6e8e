"""The access matrix (tests/reliability/access_matrix.py): every route x every kind of
credential answers as the policy says, the matrix covers every documented route, and
docs/ACCESS.md is what the service answers today."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.service.config import REPO_ROOT
from app.service.main import create_app
from tests.reliability.access_matrix import COLUMNS, POLICY, ROUTES, Matrix, expected, measure
from tests.reliability.access_matrix import render as render_matrix
from tests.service.conftest import make_settings

DOC = REPO_ROOT / "docs" / "ACCESS.md"


@pytest.fixture(scope="module")
def matrix() -> Matrix:
    return measure()


def test_every_route_answers_every_credential_as_the_policy_says(matrix: Matrix) -> None:
    wrong = [
        (r.method, r.path, c, matrix[(r.method, r.path)][c].status, POLICY[r.who][c])
        for r in ROUTES
        for c in COLUMNS
        if not expected(r, c)(matrix[(r.method, r.path)][c])
    ]
    assert wrong == []


def test_the_matrix_covers_every_documented_route(tmp_path: Path) -> None:
    schema = create_app(make_settings(tmp_path)).openapi()
    documented = {(m.upper(), p) for p, ops in schema["paths"].items() for m in ops}
    covered = {(r.method, r.path.replace("{new}", "{name}")) for r in ROUTES}
    assert documented <= covered, documented - covered


def test_docs_access_md_is_up_to_date(matrix: Matrix) -> None:
    assert DOC.read_text(encoding="utf-8") == render_matrix(matrix), (
        "docs/ACCESS.md is out of date: run "
        ".venv/bin/python -m tests.reliability.access_matrix --write docs/ACCESS.md"
    )
