"""The viewer's control panel: pickers, the kappa slider, layer toggles, the picked session,
and on a building the floor filter (every floor, or one).

The pump reads the handles' values on each tick and applies them: GUI threads never touch the
scene. A change of any control only wakes the pump (:meth:`Controls.on_change`), so a choice is
applied at once rather than after the pump's paced wait (which can last several seconds after
an expensive tick). Assigning ``.value`` or ``.options`` from code fires the same callbacks in
the assigning thread; a wake-up is all they do, and the viewer ignores the pump's own.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import viser
import viser.uplot

from app.advice.advisor import DEFAULT_KAPPA
from app.viewer.plan import CONNECTION_STYLE, GOAL_COLOUR, START_COLOUR, WALL_COLOUR
from app.viewer.scene import LAYERS, PRIOR_COLOUR, SHADE_COLOUR, SHADE_OPACITY
from app.viewer.sessions import ADVICE_MIN_P, FLOOR_COLOUR, PALETTE
from app.viewer.state import SessionView

NONE = "(none)"
#: the floor filter's first choice: every floor of a building, stacked
ALL_FLOORS = "All floors"
#: What "lost" means for the kappa shading (plain words first, the paper's symbol second).
LOST_CERTAIN = "certainly lost (P(M1|H) = 0)"
LOST_PICKED = "as the picked session (its P(M1|H))"
#: the kappa slider's range until the service says its strategies' (``Snapshot.kappa_max``):
#: just above log 4, the largest KL[theta_s || uniform], the paper's rule's range
SLIDER_KAPPA_HIGH = 1.4
#: The picked session's plot: plain words first, P(M1|H) (this quantity's one symbol on every
#: page) second.
PLOT_TITLE = "Knows the way (P(M1|H)) over time"
LAYER_LABELS = {
    "prior": "Experts' ways (prior arrows)",
    "shading": "Would be advised (kappa shading)",
    "paths": "Session paths",
    "markers": "Session markers",
    "advice": "Advice given",
}


class Controls:
    """The GUI handles of one browser (``client.gui``: each browser has its own) and what the
    person chose with them; a legend of the scene below them. Every value is read as a
    browser may have sent it, anything: a value a control would never give is put back (the
    control shows what is used)."""

    def __init__(self, gui: viser.GuiApi):
        self._shown: tuple[object, ...] | None = None
        self.domain = gui.add_dropdown("Domain", (NONE,))
        self.floor = gui.add_dropdown(
            "Floors", (ALL_FLOORS,), visible=False,
            hint="A building's floors stacked at their heights, or one floor alone, from above",
        )  # fmt: skip
        self.session = gui.add_dropdown(
            "Session", (NONE,), hint="Sessions on this domain, most recently active first"
        )
        self.fit = gui.add_button(
            "Fit the maze to the window",
            hint="Look at it from above (every floor of a building: from the south, above)",
        )
        self._fit_asked = False
        self.fit.on_click(lambda _event: self._ask_fit())
        with gui.add_folder("Where advice would be given"):
            self.kappa_high = SLIDER_KAPPA_HIGH
            self.kappa = gui.add_slider(
                "Price (kappa)", 0.0, self.kappa_high, 0.01, DEFAULT_KAPPA,
                hint="The price of one piece of advice, kappa, in nats",
            )  # fmt: skip
            self.lost = gui.add_dropdown("Lost means", (LOST_CERTAIN, LOST_PICKED))
            self.shading_text = gui.add_markdown("")
        with gui.add_folder("Layers"):
            self.layers = {
                name: gui.add_checkbox(LAYER_LABELS[name], initial_value=True) for name in LAYERS
            }
        with gui.add_folder("Picked session"):
            self.stats = gui.add_markdown("No session picked.")
            self.plot = gui.add_uplot(
                (np.zeros(1), np.full(1, 0.5)),
                (
                    viser.uplot.Series(label="step"),
                    viser.uplot.Series(label="knows the way (P(M1|H))", stroke="#326edc", width=2),
                ),
                title=PLOT_TITLE,
                scales={"x": viser.uplot.Scale(time=False), "y": viser.uplot.Scale(range=(0, 1))},
                aspect=1.6,
                visible=False,
            )
        with gui.add_folder("Legend"):
            self.legend = gui.add_markdown(legend_markdown())

    def on_change(self, callback: Callable[[], None]) -> None:
        """Call ``callback`` (it must be quick: it runs in the changing thread) whenever a
        control changes, from a browser or from code."""
        inputs: tuple[viser.GuiInputHandle[Any], ...] = (
            self.domain,
            self.floor,
            self.session,
            self.kappa,
            self.lost,
            *self.layers.values(),
        )
        for handle in inputs:
            handle.on_update(lambda _event: callback())
        self.fit.on_click(lambda _event: callback())

    def _ask_fit(self) -> None:
        self._fit_asked = True

    def take_fit(self) -> bool:
        """Whether the person asked for the maze to be fitted since the last call."""
        asked, self._fit_asked = self._fit_asked, False
        return asked

    # ---- reading the choices -------------------------------------------------------------
    @property
    def picked_domain(self) -> str | None:
        value = picked(self.domain)
        return None if value == NONE else value

    @property
    def picked_floor(self) -> int | None:
        """The floor shown alone (its index among the building's, lowest first), None for
        every floor (and on a one-floor map)."""
        value = picked(self.floor)
        return None if value == ALL_FLOORS else self.floor.options.index(value) - 1

    @property
    def picked_session(self) -> str | None:
        value = picked(self.session)
        return None if value == NONE else value

    @property
    def lost_mode(self) -> str:
        return picked(self.lost)

    @property
    def picked_kappa(self) -> float:
        """The slider's kappa, within [0, :attr:`kappa_high`]. Any page can open the viewer's
        websocket and send a value the slider would never give (NaN, -5, 1e308, text): such a
        value is put back in range (NaN and non-numbers: the default) and the slider shows
        it."""
        value = self.kappa.value
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = DEFAULT_KAPPA
        if isinstance(value, bool) or not math.isfinite(v):
            v = DEFAULT_KAPPA
        v = min(max(v, 0.0), self.kappa_high)
        if isinstance(value, bool) or not isinstance(value, float):
            # viser's setter casts to the type of the value it holds: give it a float first
            self.kappa._impl.value = v
        if value != v or not isinstance(value, float):
            self.kappa.value = v  # type: ignore[misc]  # viser types no setter; it has one
        return v

    def layer_visible(self, layer: str) -> bool:
        box = self.layers[layer]
        if not isinstance(box.value, bool):  # what a raw message can leave there
            box._impl.value = False  # viser's setter casts to the held value's type
            box.value = True
        return bool(box.value)

    def set_kappa_high(self, high: float) -> None:
        """The slider reaches ``high`` (every strategy's range: the service says it)."""
        if high != self.kappa_high and math.isfinite(high) and high > 0.0:
            self.kappa_high = high
            self.kappa.max = high

    # ---- refreshing from the pump --------------------------------------------------------
    def set_domains(self, names: Sequence[str]) -> None:
        set_options(self.domain, tuple(names) or (NONE,))

    def set_floors(self, names: Sequence[str]) -> None:
        """The floors of the domain shown (lowest first; none: a one-floor map, and the filter
        is hidden); the legend says what a building adds."""
        set_options(self.floor, (ALL_FLOORS, *names))
        if self.floor.visible != bool(names):
            self.floor.visible = bool(names)
            self.legend.content = legend_markdown(floors=bool(names))

    def set_sessions(self, ids: Sequence[str]) -> None:
        set_options(self.session, (NONE, *ids))

    def show_shading(self, cells: int, total: int, kappa: float, p_normal: float) -> None:
        self.shading_text.content = (
            f"Shaded: **{cells}** of {total} cells, where an explorer who looks lost "
            f"{1.0 - p_normal:.0%} (P(M1|H) = {p_normal:.3f}) would be advised at the price "
            f"of advice kappa = {kappa:.2f} (where KL[theta_s || P(A|s,H)] >= kappa)."
        )

    def show_session(self, s: SessionView | None) -> None:
        key = None if s is None else (s.session_id, s.version, s.p_normal, s.figures, s.leads_to)
        if key == self._shown:
            return
        self._shown = key
        if s is None:
            self.stats.content = "No session picked."
            self.plot.visible = False
            return
        per_100 = 100.0 * s.advice_count / (s.steps + 1)
        self.stats.content = (
            f"**{s.session_id}**" + (f" ({s.agent_type})" if s.agent_type else "") + "\n\n"
            f"steps **{s.steps}**, at {list(s.position)}\n\n"
            + belief_lines(s)
            + f"advice **{s.advice_count}** ({per_100:.1f} per 100 decisions), "
            f"cost **{s.total_cost:.2f}** at the price {s.kappa:g} (kappa), "
            f"strategy `{s.strategy}`" + goal_lines(s)
        )
        history = np.asarray(s.p_normal_history, dtype=np.float64)
        if history.size == 0:
            history = np.array([s.p_normal])
        steps = np.arange(s.steps - history.size + 1, s.steps + 1, dtype=np.float64)
        self.plot.data = (steps, history)
        self.plot.visible = True


def swatch(rgb: npt.ArrayLike, shape: str = "■") -> str:
    """A coloured symbol for the legend (viser's markdown takes inline HTML)."""
    r, g, b = (int(v) for v in np.asarray(rgb).ravel()[:3])
    return f'<span style="color: #{r:02x}{g:02x}{b:02x}">{shape}</span>'


def legend_markdown(floors: bool = False) -> str:
    """What each thing in the scene is, in the scene's own colours (``floors``: with what a
    building of several floors adds)."""
    sessions = "".join(swatch(c, "●") for c in PALETTE[:5])
    # the shading is drawn translucent on the floor: its swatch is the colour that results
    shade = SHADE_OPACITY * np.array(SHADE_COLOUR) + (1 - SHADE_OPACITY) * np.array(FLOOR_COLOUR)
    ways = ", ".join(
        f"{swatch(colour)} {kind}" for kind, (colour, _, _) in CONNECTION_STYLE.items()
    )
    building = [
        f"**Floors**: stacked at their heights, each named at its corner; {ways}: the "
        "connections between floors (stairs and escalators zigzag, lifts and ramps go "
        "straight), their stops tiled on each floor. Up and down (U, D) are arrows standing "
        "upright. *Floors* shows one floor alone, from above",
    ]
    return "\n\n".join(
        [
            f"{swatch(WALL_COLOUR)} walls, {swatch(START_COLOUR)} start, "
            f"{swatch(GOAL_COLOUR)} destinations, by name or G0, G1, ... (the explorer's "
            "hidden goal is one of them)",
            f"{swatch(PRIOR_COLOUR, '➤')} **{LAYER_LABELS['prior']}**: what people who know "
            "the building did in each cell (the experts' action prior theta_s), four flat "
            "arrows a cell; the longer and more solid, the more often experts moved that way "
            "there",
            f"{swatch(shade)} **{LAYER_LABELS['shading']}**: cells where an explorer who "
            "looks as lost as *Lost means* says would be advised at the slider's price "
            "(kappa): where KL[theta_s || P(A|s,H)] >= kappa",
            f"{sessions} **Session markers**: where each live explorer is now, one colour "
            "each; ▶ labels the picked one",
            f"{swatch(PALETTE[0], '━')} **Session paths**: each explorer's recent cells as a "
            "line in its colour, older parts fading into the floor",
            f"{swatch(PALETTE[0], '↑')} **Advice given**: arrows in the explorer's colour "
            "from each cell where it was advised, one per move, as long as the advice's "
            f"probability of that move (under {ADVICE_MIN_P:.0%} not drawn)",
            *(building if floors else []),
        ]
    )


def goal_lines(s: SessionView) -> str:
    """goal_aware sessions: P(goal | H) per goal of the map (G0.. in the scene's order), and
    which goals are ruled out (the explorer stood there and went on)."""
    if s.goals is None:
        return ""
    rows = [
        f"G{i} {list(cell)}: " + ("~~ruled out~~" if out else f"**{p:.2f}**")
        for i, (cell, p, out) in enumerate(s.goals)
    ]
    return "\n\nWhere it may be going (P(goal|H)): " + ", ".join(rows)


#: how each tone reads in the panel (the strategy decides the tone, not the viewer)
TONE_MARK = {"good": "", "neutral": " (being handled)", "bad": " ⚠"}


def belief_lines(s: SessionView) -> str:
    """What its advisor believes, plain words first and the paper's symbol second, the one
    that says most in bold; where its advice leads. A feed without beliefs: P(M1|H)."""
    if not s.figures:
        return f"knows the way **{s.p_normal:.0%}** (P(M1|H) {s.p_normal:.3f})\n\n"
    lines = []
    for i, f in enumerate(s.figures):
        value = f"**{f.p:.0%}**" if i == s.headline else f"{f.p:.0%}"
        mark = TONE_MARK.get(f.tone, "") if i == s.headline else ""
        lines.append(f"{markdown_text(f.name)} {value} ({markdown_text(f.symbol)}){mark}")
    out = "; ".join(lines) + "\n\n"
    if s.leads_to is not None:
        to = s.leads_to
        out += f"advice leads to **{markdown_text(to.label)}** {list(to.cell)}\n\n"
    return out


def markdown_text(text: str) -> str:
    """``text`` shown as it is in viser's markdown (which takes inline HTML): every character
    that markdown or HTML reads escaped."""
    return "".join(f"\\{c}" if c in MARKDOWN_SPECIAL else c for c in text).replace("<", "&lt;")


MARKDOWN_SPECIAL = set("\\`*_{}[]()#+-.!|~>")


def picked(dropdown: viser.GuiDropdownHandle[str]) -> str:
    """The dropdown's value if it is one of its options; else (a browser's message may hold
    anything) its first option, which the dropdown then shows."""
    value = dropdown.value
    if isinstance(value, str) and value in dropdown.options:
        return value
    first = dropdown.options[0]
    dropdown._impl.value = ""  # viser's setter casts to the held value's type, and sends
    dropdown.value = first  # type: ignore[misc]  # a change from "": the first is sent
    return first


def set_options(dropdown: viser.GuiDropdownHandle[str], options: tuple[str, ...]) -> None:
    """Replace a dropdown's options only when they changed (each assignment is a message)."""
    if tuple(dropdown.options) != options:
        dropdown.options = options
