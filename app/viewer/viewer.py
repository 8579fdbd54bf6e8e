"""The live viewer: a viser server, the maze scene and its controls, driven by a pump.

The pump is a daemon thread that, ``rate_hz`` times a second, takes one :class:`Snapshot` from
the feed and brings the scene up to date, inside ``server.atomic()``. Nothing is drawn per
event, so however fast explorers report, the viewer costs the service one snapshot per tick.

The pump shares the service's process (and its GIL), so it also paces itself: with no browser
connected it ticks only ``idle_rate_hz`` times a second (enough to keep the pickers current),
and after an expensive tick it waits long enough that ticking takes at most ``max_share`` of
the time (many busy sessions then lower the frame rate, not the API's throughput). What a person
does cuts the wait short: a browser connecting, or any control changing, wakes the pump for one
tick at once, so a choice never waits for the pacing.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import viser

from app.viewer.controls import LOST_PICKED, Controls
from app.viewer.scene import LAYERS, MazeScene, top_down_camera
from app.viewer.state import DomainView, Feed, Snapshot

log = logging.getLogger(__name__)

DEFAULT_PORT = 8080
DEFAULT_RATE_HZ = 10.0
IDLE_RATE_HZ = 1.0
MAX_SHARE = 0.10
#: At most this many sessions are drawn (the most advanced ones), to keep the scene light.
MAX_DRAWN_SESSIONS = 64


class Viewer:
    """Serve the scene on ``host:port`` and keep it in step with ``feed``."""

    def __init__(
        self,
        feed: Feed,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        rate_hz: float = DEFAULT_RATE_HZ,
        idle_rate_hz: float = IDLE_RATE_HZ,
        max_share: float = MAX_SHARE,
        on_tick: Callable[[float], None] | None = None,
    ):
        for name, value in (("rate_hz", rate_hz), ("idle_rate_hz", idle_rate_hz)):
            if not value > 0:
                raise ValueError(f"{name} must be positive, got {value}")
        if not 0 < max_share <= 1:
            raise ValueError(f"max_share must be in (0, 1], got {max_share}")
        self.feed = feed
        self.host = host
        self.requested_port = port
        self.period = 1.0 / rate_hz
        self.idle_period = 1.0 / idle_rate_hz
        self.max_share = max_share
        #: called with each pump tick's duration in seconds (the service's metrics hook)
        self.on_tick = on_tick
        self.server: viser.ViserServer | None = None
        self.controls: Controls | None = None
        self.scene: MazeScene | None = None
        self.ticks = 0
        self._drawn: tuple[str, int] | None = None  # (domain name, prior version)
        self._stop = threading.Event()
        self._wake = threading.Event()  # a control changed or a browser connected: tick now
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    # ---- lifecycle -----------------------------------------------------------------------
    def start(self, pump: bool = True) -> None:
        """Start the web server (and, unless ``pump`` is false, the pump thread)."""
        server = viser.ViserServer(host=self.host, port=self.requested_port, verbose=False)
        server.gui.configure_theme(
            titlebar_content=None, control_width="medium", show_share_button=False
        )
        # a flat, evenly lit map: no environment reflections, no shadows (cheap in software GL)
        server.scene.configure_environment_map(hdri=None)
        server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        self.server = server
        self.controls = Controls(server)
        self.controls.on_change(self._changed)
        server.on_client_connect(self._on_connect)
        log.info("viewer on http://%s:%d", self.host, self.port)
        if pump:
            self._thread = threading.Thread(target=self._run, name="viewer-pump", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self.server is not None:
            self.server.stop()

    @property
    def port(self) -> int:
        """The port actually bound (viser moves on if the requested one is busy)."""
        return self.server.get_port() if self.server else self.requested_port

    def _changed(self) -> None:
        """A control changed: tick now (a change the pump made itself needs no tick)."""
        if threading.current_thread() is not self._thread:
            self._wake.set()

    def _on_connect(self, client: viser.ClientHandle) -> None:
        """A browser connected: aim its camera, and tick now (not after an idle wait)."""
        self._aim(client)
        self._wake.set()

    def _aim(self, client: viser.ClientHandle) -> None:
        if self.scene is not None:
            position, look_at, up = top_down_camera(self.scene.domain)
            client.camera.up_direction = tuple(up)
            client.camera.position = tuple(position)
            client.camera.look_at = tuple(look_at)

    def _run(self) -> None:
        wait = 0.0
        while True:
            self._wake.wait(wait)
            if self._stop.is_set():
                return
            self._wake.clear()
            watched = self.server is not None and bool(self.server.get_clients())
            started = time.perf_counter()
            try:
                self.tick()
            except Exception:  # keep pumping: the next snapshot may be fine
                log.exception("viewer pump tick failed")
            took = time.perf_counter() - started
            if self.on_tick is not None:
                self.on_tick(took)
            period = self.period if watched else self.idle_period
            wait = pump_wait(took, period, self.max_share)

    # ---- one tick ------------------------------------------------------------------------
    def tick(self) -> None:
        """Bring the scene up to date with one snapshot (the pump calls this)."""
        assert self.server is not None and self.controls is not None, "call start() first"
        snapshot = self.feed()
        with self._lock, self.server.atomic():
            self._apply(snapshot)
        self.ticks += 1

    def _apply(self, snap: Snapshot) -> None:
        controls = self.controls
        assert controls is not None
        controls.set_domains(sorted(snap.domains))
        view = snap.domains.get(controls.picked_domain or "")
        if view is None:
            self._clear()
            return
        self._draw_domain(view)
        scene = self.scene
        assert scene is not None
        sessions = sorted(snap.sessions_of(view.name), key=lambda s: s.session_id)
        controls.set_sessions([s.session_id for s in sessions])
        picked = next((s for s in sessions if s.session_id == controls.picked_session), None)
        drawn = sorted(sessions, key=lambda s: -s.steps)[:MAX_DRAWN_SESSIONS]
        if picked is not None and picked not in drawn:
            drawn.append(picked)
        scene.update_sessions(drawn, picked.session_id if picked else None)
        for layer in LAYERS:
            scene.set_layer(layer, controls.layer_visible(layer))
        kappa = controls.picked_kappa
        p = picked.p_normal if picked is not None and controls.lost.value == LOST_PICKED else 0.0
        shaded = scene.shade(view.theta, kappa, p)
        controls.show_shading(shaded, view.domain.n_states, kappa, p)
        controls.show_session(picked)

    def _draw_domain(self, view: DomainView) -> None:
        assert self.server is not None
        if self.scene is not None and self.scene.domain is view.domain:
            if self._drawn != (view.name, view.prior_version):
                self.scene.set_prior(view.theta)
                self._drawn = (view.name, view.prior_version)
            return
        self._clear()
        self.scene = MazeScene(self.server, view.domain, view.theta)
        self._drawn = (view.name, view.prior_version)
        position, look_at, up = top_down_camera(view.domain)
        cam = self.server.initial_camera
        cam.position, cam.look_at, cam.up = tuple(position), tuple(look_at), tuple(up)
        for client in self.server.get_clients().values():
            self._aim(client)

    def _clear(self) -> None:
        if self.scene is not None:
            self.scene.remove()
            self.scene = None
            self._drawn = None
        if self.controls is not None:
            self.controls.set_sessions([])
            self.controls.show_session(None)


def pump_wait(elapsed: float, period: float, max_share: float) -> float:
    """Seconds to wait after a tick that took ``elapsed``: the rest of ``period``, but at least
    long enough that ticking takes no more than ``max_share`` of the time."""
    return max(period - elapsed, elapsed * (1.0 - max_share) / max_share)
