"""What an advisor believes of its explorer, in plain words, as the pages show it.

Each strategy's entry (:class:`~app.strategies.entry.Strategy`) has a ``beliefs`` hook that
reads its advisor and the P(M1|H) of its last decision and answers :class:`Beliefs`: a few
figures, each a probability with a plain name first and the paper's (or the strategy's) symbol
second, and a tone the strategy decides (``good``: nothing to do; ``neutral``: the advisor is
handling it; ``bad``: it looks lost and the advisor cannot help now), so that no page decides
what a number means; and the destination its advice leads to, if it leads to one. The pages
(dashboard, ``/walk``, the 3D viewer) show them through the session answers
(``SessionPublic.beliefs``, the overview, the viewer's feed).

:func:`paper_beliefs` is every strategy's default: the paper's P(M1|H) ("moves like someone
who knows the building") and P(M2|H) = 1 - P(M1|H) ("looks lost"). :func:`guide_beliefs`
reads ``guide``'s: lost, on its way, and the destination it leads to.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from app.advice.advisor import Advisor

Tone = Literal["good", "neutral", "bad"]

#: the paper's two figures, in plain words
KNOWS_THE_WAY = "moves like someone who knows the building"
LOOKS_LOST = "looks lost"
ON_ITS_WAY = "on its way"
TAKES_ADVICE = "takes the advice"


@dataclass(frozen=True, slots=True)
class Figure:
    """One thing the advisor believes: ``p`` (0 to 1) that the explorer is as ``name`` says
    (plain words), written ``symbol`` in the paper's notation, and how it reads (``tone``)."""

    name: str
    symbol: str
    p: float
    tone: Tone


@dataclass(frozen=True, slots=True)
class Beliefs:
    """The figures in a fixed order, which one says most (``headline``, an index), and the
    destination (an index into the domain's goals) the advice leads to, if any."""

    figures: tuple[Figure, ...]
    headline: int = 0
    leads_to: int | None = None


def paper_beliefs(advisor: Advisor, p_normal: float) -> Beliefs:
    """The paper's posterior over its two models (eq. (5)) at the last decision: M1,
    normalcy, and M2, uniform moves; ``bad`` below one half (the explorer looks lost)."""
    p = p_normal
    knows = Figure(KNOWS_THE_WAY, "P(M1|H)", p, "good" if p >= 0.5 else "bad")
    lost = Figure(LOOKS_LOST, "P(M2|H)", 1.0 - p, "bad" if p < 0.5 else "good")
    return Beliefs((knows, lost), headline=0 if p >= 0.5 else 1)


def guide_target(advisor: Advisor) -> int | None:
    """The destination ``guide``'s advice leads to now (None before its first decision, or
    where none can be reached): its advisor's ``target``."""
    target: int = getattr(advisor, "target", -1)
    return target if target >= 0 else None


def guide_beliefs(advisor: Advisor, p_normal: float) -> Beliefs:
    """``guide``'s reading (app/advice/guide.py): its decisions report P(M1|H) = 1 -
    P(lost|H), where P(lost|H) is the sum over its lost models ("looks lost") and the rest
    the models of someone on its way to a destination ("on its way"); and the destination it
    leads to (:func:`guide_target`). A lost explorer that guide is leading reads ``neutral``,
    not ``bad``: following advice is what guide asks of it. ``bad`` only when it looks lost and
    guide cannot lead it now (no destination reachable, or no advice left: its budget is spent
    or the visitor muted it). Third, how often it takes the advice, as guide has learned it
    ("takes the advice", the posterior mean of its compliance): ``neutral`` while guide holds
    advice back from a visitor who ignores it, else ``good``."""
    lost = 1.0 - p_normal
    target = guide_target(advisor)
    leading = target is not None and advisor.advice_count < advisor.cap
    looks_lost = lost >= 0.5
    lost_tone: Tone = "good" if not looks_lost else ("neutral" if leading else "bad")
    figures: tuple[Figure, ...] = (
        Figure(LOOKS_LOST, "P(lost|H)", lost, lost_tone),
        Figure(ON_ITS_WAY, "P(M1|H)", p_normal, lost_tone),
    )
    takes = getattr(advisor, "compliance", None)
    if takes is not None:
        held: Tone = "neutral" if getattr(advisor, "holding_back", False) else "good"
        figures += (Figure(TAKES_ADVICE, "P(take)", float(takes), held),)
    return Beliefs(figures, headline=0 if looks_lost else 1, leads_to=target)
