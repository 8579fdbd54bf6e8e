"""The live viewer: a viser server, a scene and controls for each browser, driven by a pump.

It runs in a process of its own (``python -m app viewer``, which ``serve`` starts), fed by the
API's snapshots over HTTP (:mod:`app.viewer.remote`): nothing a browser sends reaches the API's
memory or its event loop. Each browser has its own controls and scene (:class:`ClientView`);
every value it sends is checked (:mod:`app.viewer.controls`) and its messages are bounded
(:mod:`app.viewer.guard`).

The pump is a daemon thread that, ``rate_hz`` times a second while a browser is connected,
takes one :class:`Snapshot` from the feed and brings each browser's scene up to date, inside
its ``client.atomic()``. Nothing is drawn per event, so however fast explorers report, the
viewer costs the service one snapshot per tick; with no browser it does not tick at all. After
an expensive tick it waits long enough that ticking takes at most ``max_share`` of the time.
What a person does cuts the wait short: a browser connecting, or any control changing, wakes
the pump for one tick at once, so a choice never waits for the pacing.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import viser

from app.domain.building import Building
from app.viewer.controls import LOST_PICKED, Controls
from app.viewer.guard import MAX_CLIENTS, bounded_server, client_without_uploads
from app.viewer.scene import DEFAULT_FOV, LAYERS, MazeScene
from app.viewer.state import DomainView, Feed, Snapshot

log = logging.getLogger(__name__)

DEFAULT_PORT = 8080
DEFAULT_RATE_HZ = 10.0
IDLE_RATE_HZ = 1.0
MAX_SHARE = 0.10
#: At most this many sessions are drawn (the most advanced ones), to keep the scene light.
MAX_DRAWN_SESSIONS = 64


class ClientView:
    """What one browser sees: its own controls (``client.gui``) and its own scene
    (``client.scene``), so that one browser's choices never change another's view."""

    def __init__(self, client: viser.ClientHandle):
        self.client = client
        self.controls = Controls(client.gui)
        self.scene: MazeScene | None = None
        self._drawn: tuple[str, int] | None = None  # (domain name, prior version)
        # the canvas size and the floor shown (None: all) the camera was fitted to
        self._aimed: tuple[tuple[int, int], int | None] | None = None

    def apply(self, snap: Snapshot) -> None:
        """Bring this browser's scene and panel up to date with ``snap``."""
        controls = self.controls
        if snap.kappa_max is not None:
            controls.set_kappa_high(snap.kappa_max)
        controls.set_domains(sorted(snap.domains))
        view = snap.domains.get(controls.picked_domain or "")
        if view is None:
            controls.set_floors([])
            self.clear()
            return
        self._draw_domain(view)
        scene = self.scene
        assert scene is not None
        domain = view.domain
        controls.set_floors([f.name for f in domain.floors] if isinstance(domain, Building) else [])
        scene.show_floor(controls.picked_floor)
        if controls.take_fit() or self._aimed != (canvas_of(self.client), scene.shown_floor):
            self.aim()  # asked for, the window changed size or another floor: fill it again
        sessions = snap.sessions_of(view.name)  # most recently active first, as the feed has them
        controls.set_sessions([s.session_id for s in sessions])
        picked = next((s for s in sessions if s.session_id == controls.picked_session), None)
        drawn = sorted(sessions, key=lambda s: -s.steps)[:MAX_DRAWN_SESSIONS]
        if picked is not None and picked not in drawn:
            drawn.append(picked)
        scene.update_sessions(drawn, picked.session_id if picked else None)
        for layer in LAYERS:
            scene.set_layer(layer, controls.layer_visible(layer))
        kappa, lost = controls.picked_kappa, controls.lost_mode  # both checked every tick
        p = picked.p_normal if picked is not None and lost == LOST_PICKED else 0.0
        shaded = scene.shade(view.theta, kappa, p)
        controls.show_shading(shaded, view.domain.n_states, kappa, p)
        controls.show_session(picked)

    def _draw_domain(self, view: DomainView) -> None:
        if self.scene is not None and self.scene.domain is view.domain:
            if self._drawn != (view.name, view.prior_version):
                self.scene.set_prior(view.theta)
                self._drawn = (view.name, view.prior_version)
            return
        self.clear()
        self.scene = MazeScene(self.client, view.domain, view.theta)
        self._drawn = (view.name, view.prior_version)
        self.aim()

    def aim(self) -> None:
        """Look at this browser's map from above, north up, the map filling its canvas (a
        building's floors, all of them, from the south and above: :meth:`MazeScene.camera`)."""
        if self.scene is not None:
            fov, aspect = view_of(self.client)
            position, look_at, up = self.scene.camera(fov, aspect)
            self._aimed = (canvas_of(self.client), self.scene.shown_floor)
            camera = self.client.camera
            camera.up_direction = tuple(up)
            camera.position = tuple(position)
            camera.look_at = tuple(look_at)

    def clear(self) -> None:
        if self.scene is not None:
            self.scene.remove()
            self.scene = None
            self._drawn = None
        self.controls.set_sessions([])
        self.controls.show_session(None)


def canvas_of(client: viser.ClientHandle) -> tuple[int, int]:
    """The size in pixels of the browser's canvas, as it last said ((0, 0) for what is not a
    size: a browser may send anything)."""
    camera = client.camera
    try:
        return (int(camera.image_width), int(camera.image_height))
    except (TypeError, ValueError, OverflowError):
        return (0, 0)


def view_of(client: viser.ClientHandle) -> tuple[float, float]:
    """(vertical field of view in radians, aspect) of the browser's camera; what is not a
    usable value is replaced by viser's default field of view (75 degrees) or a square view."""
    try:
        fov = float(client.camera.fov)
    except (TypeError, ValueError):
        fov = DEFAULT_FOV
    fov = fov if math.radians(5.0) <= fov <= math.radians(170.0) else DEFAULT_FOV
    width, height = canvas_of(client)
    aspect = width / height if width > 0 and height > 0 else 1.0
    return fov, aspect if 0.05 <= aspect <= 20.0 else 1.0


class Viewer:
    """Serve the scene on ``host:port`` and keep every browser's view in step with ``feed``.

    The web server is viser's, with the bounds of :mod:`app.viewer.guard` (message sizes, the
    page's origin, the number of browsers, no uploads); ``origins``: page origins allowed
    beyond its own (:func:`app.viewer.guard.origins`). Each browser gets a
    :class:`ClientView` when it connects."""

    def __init__(
        self,
        feed: Feed,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        rate_hz: float = DEFAULT_RATE_HZ,
        idle_rate_hz: float = IDLE_RATE_HZ,
        max_share: float = MAX_SHARE,
        max_clients: int = MAX_CLIENTS,
        on_tick: Callable[[float], None] | None = None,
        origins: tuple[str, ...] = (),
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
        self.max_clients = max_clients
        self.origins = origins  # page origins allowed beyond its own (guard.origins)
        self.on_tick = on_tick  # called with each tick's duration in seconds (metrics)
        self.server: viser.ViserServer | None = None
        self.views: dict[int, ClientView] = {}
        self.ticks = 0
        self._stop = threading.Event()
        self._wake = threading.Event()  # a control changed or a browser connected: tick now
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    # ---- lifecycle -----------------------------------------------------------------------
    def start(self, pump: bool = True) -> None:
        """Start the web server (and, unless ``pump`` is false, the pump thread)."""
        server = bounded_server(
            self.host, self.requested_port, max_clients=self.max_clients,
            extra_origins=self.origins,
        )  # fmt: skip
        server.gui.configure_theme(
            titlebar_content=None, control_width="medium", show_share_button=False
        )
        # docked, the panel takes its width from the canvas (not floating over it), so the
        # canvas size a browser reports is the part the maze can fill
        server.gui.main_panel.dock_right()
        # a flat, evenly lit map: no environment reflections, no shadows (cheap in software GL)
        server.scene.configure_environment_map(hdri=None)
        server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        self.server = server
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)
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

    @property
    def controls(self) -> Controls | None:
        """The controls of the first browser connected (None without one)."""
        view = next(iter(self.views.values()), None)
        return view.controls if view is not None else None

    @property
    def scene(self) -> MazeScene | None:
        """The scene of the first browser connected (None without one, or no domain)."""
        view = next(iter(self.views.values()), None)
        return view.scene if view is not None else None

    def _changed(self) -> None:
        """A control changed: tick now (a change the pump made itself needs no tick)."""
        if threading.current_thread() is not self._thread:
            self._wake.set()

    def _on_connect(self, client: viser.ClientHandle) -> None:
        """A browser connected: its own controls and scene; tick now (not after a wait)."""
        client_without_uploads(client)
        view = ClientView(client)
        view.controls.on_change(self._changed)
        with self._lock:
            self.views[client.client_id] = view
        self._wake.set()

    def _on_disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            self.views.pop(client.client_id, None)

    def _run(self) -> None:
        wait = 0.0
        failed = ""  # the last failure logged: a service that is down is said once, not per tick
        while True:
            self._wake.wait(wait)
            if self._stop.is_set():
                return
            self._wake.clear()
            watched = bool(self.views)
            started = time.perf_counter()
            try:
                if watched:
                    self.tick()
                    failed = ""
            except Exception as exc:  # keep pumping: the next snapshot may be fine
                if str(exc) != failed:
                    log.warning("viewer pump tick failed: %s: %s", type(exc).__name__, exc)
                    failed = str(exc)
            period = self.period if watched else self.idle_period
            wait = pump_wait(time.perf_counter() - started, period, self.max_share)

    # ---- one tick ------------------------------------------------------------------------
    def tick(self) -> None:
        """Bring every browser's view up to date with one snapshot (the pump calls this)."""
        assert self.server is not None, "call start() first"
        started = time.perf_counter()
        snapshot = self.feed()
        with self._lock:
            for view in list(self.views.values()):
                with view.client.atomic():
                    view.apply(snapshot)
        self.ticks += 1
        if self.on_tick is not None:
            self.on_tick(time.perf_counter() - started)


def pump_wait(elapsed: float, period: float, max_share: float) -> float:
    """Seconds to wait after a tick that took ``elapsed``: the rest of ``period``, but at least
    long enough that ticking takes no more than ``max_share`` of the time."""
    return max(period - elapsed, elapsed * (1.0 - max_share) / max_share)
