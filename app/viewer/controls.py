"""The viewer's control panel: pickers, the kappa slider, layer toggles, the picked session.

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
import viser
import viser.uplot

from app.advice.advisor import DEFAULT_KAPPA
from app.viewer.scene import LAYERS
from app.viewer.state import SessionView

NONE = "(none)"
#: What "lost" means for the kappa shading.
LOST_CERTAIN = "P(M1|H) = 0: certainly lost"
LOST_PICKED = "P(M1|H) of the picked session"
KAPPA_MAX = 1.4  # just above log 4, the largest KL[theta_s || uniform]
LAYER_LABELS = {
    "prior": "Prior arrows",
    "shading": "Kappa shading",
    "paths": "Session paths",
    "markers": "Session markers",
    "advice": "Advice given",
}


class Controls:
    """The GUI handles of one browser (``client.gui``: each browser has its own) and what the
    person chose with them. Every value is read as a browser may have sent it, anything: a
    value a control would never give is put back (the control shows what is used)."""

    def __init__(self, gui: viser.GuiApi):
        self._shown: tuple[object, ...] | None = None
        self.domain = gui.add_dropdown("Domain", (NONE,))
        self.session = gui.add_dropdown("Session", (NONE,), hint="Sessions on this domain")
        with gui.add_folder("Advice threshold"):
            self.kappa = gui.add_slider(
                "kappa", 0.0, KAPPA_MAX, 0.01, DEFAULT_KAPPA, hint="Cost of one piece of advice"
            )
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
                    viser.uplot.Series(label="P(M1|H)", stroke="#326edc", width=2),
                ),
                title="p_normal over time",
                scales={"x": viser.uplot.Scale(time=False), "y": viser.uplot.Scale(range=(0, 1))},
                aspect=1.6,
                visible=False,
            )

    def on_change(self, callback: Callable[[], None]) -> None:
        """Call ``callback`` (it must be quick: it runs in the changing thread) whenever a
        control changes, from a browser or from code."""
        inputs: tuple[viser.GuiInputHandle[Any], ...] = (
            self.domain,
            self.session,
            self.kappa,
            self.lost,
            *self.layers.values(),
        )
        for handle in inputs:
            handle.on_update(lambda _event: callback())

    # ---- reading the choices -------------------------------------------------------------
    @property
    def picked_domain(self) -> str | None:
        value = picked(self.domain)
        return None if value == NONE else value

    @property
    def picked_session(self) -> str | None:
        value = picked(self.session)
        return None if value == NONE else value

    @property
    def lost_mode(self) -> str:
        return picked(self.lost)

    @property
    def picked_kappa(self) -> float:
        """The slider's kappa, within [0, KAPPA_MAX]. Any page can open the viewer's websocket
        and send a value the slider would never give (NaN, -5, 1e308, text): such a value is
        put back in range (NaN and non-numbers: the default) and the slider shows it."""
        value = self.kappa.value
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = DEFAULT_KAPPA
        if isinstance(value, bool) or not math.isfinite(v):
            v = DEFAULT_KAPPA
        v = min(max(v, 0.0), KAPPA_MAX)
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

    # ---- refreshing from the pump --------------------------------------------------------
    def set_domains(self, names: Sequence[str]) -> None:
        set_options(self.domain, tuple(names) or (NONE,))

    def set_sessions(self, ids: Sequence[str]) -> None:
        set_options(self.session, (NONE, *ids))

    def show_shading(self, cells: int, total: int, kappa: float, p_normal: float) -> None:
        self.shading_text.content = (
            f"Shaded: **{cells}** of {total} cells would be advised at kappa = {kappa:.2f} "
            f"for an explorer with P(M1|H) = {p_normal:.3f} "
            "(advise iff KL[theta_s || P(A|s,H)] >= kappa)."
        )

    def show_session(self, s: SessionView | None) -> None:
        key = None if s is None else (s.session_id, s.version, s.p_normal)
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
            f"steps **{s.steps}**, at {list(s.position)}, P(M1|H) **{s.p_normal:.3f}**\n\n"
            f"advice **{s.advice_count}** ({per_100:.1f} per 100 decisions), "
            f"cost **{s.total_cost:.2f}** at kappa {s.kappa:g}, strategy `{s.strategy}`"
            + goal_lines(s)
        )
        history = np.asarray(s.p_normal_history, dtype=np.float64)
        if history.size == 0:
            history = np.array([s.p_normal])
        steps = np.arange(s.steps - history.size + 1, s.steps + 1, dtype=np.float64)
        self.plot.data = (steps, history)
        self.plot.visible = True


def goal_lines(s: SessionView) -> str:
    """goal_aware sessions: P(goal | H) per goal of the map (G0.. in the scene's order), and
    which goals are ruled out (the explorer stood there and went on)."""
    if s.goals is None:
        return ""
    rows = [
        f"G{i} {list(cell)}: " + ("~~ruled out~~" if out else f"**{p:.2f}**")
        for i, (cell, p, out) in enumerate(s.goals)
    ]
    return "\n\nGoal posterior: " + ", ".join(rows)


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
