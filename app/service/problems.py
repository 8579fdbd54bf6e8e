"""What a client got wrong: :class:`BadInput`, and pydantic's errors in one readable line."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from app.service.schemas import ACTION_BRANCHES, ACTION_RULE


class BadInput(ValueError):
    """A client error: ``detail`` says what was wrong; ``status`` is the HTTP code;
    ``headers``: of the answer (``Retry-After``)."""

    def __init__(self, detail: str, status: int = 422, headers: dict[str, str] | None = None):
        super().__init__(detail)
        self.detail = detail
        self.status = status
        self.headers = headers


def where(loc: Sequence[int | str]) -> str:
    """A validation error location as a path: ``trajectories[0].steps[3].action``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "body"


def describe_errors(errors: Sequence[Any], limit: int = 5) -> str:
    """Pydantic errors in one readable line: ``where: what`` for the first few (the two
    branches of an action's union reported once, as one rule)."""
    parts: list[str] = []
    for e in errors:
        loc = tuple(e["loc"])
        text = f"{where(loc)}: {e['msg']}"
        if loc and loc[-1] in ACTION_BRANCHES:
            text = f"{where(loc[:-1])}: {ACTION_RULE}"
        if text not in parts:
            parts.append(text)
    more = f" (and {len(parts) - limit} more)" if len(parts) > limit else ""
    return "; ".join(parts[:limit]) + more
