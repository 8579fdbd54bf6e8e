"""The viser server with the bounds a browser-facing socket needs.

viser 1.1.1 accepts websocket messages of up to 50 MB from any page (no Origin check), buffers
file-upload parts aimed at a GUI element without limit, and takes any number of browsers. The
viewer's server is made by :func:`bounded_server`, which has viser open its websocket server
with:

* ``max_size``: a browser's message over it closes the connection (1009) before it is read;
* ``max_queue``: at most a few unread messages per browser;
* ``origins``: a websocket from a page of another origin is refused (403): a page on the web
  can no longer drive the viewer through the operator's browser (clients that send no Origin,
  programs on this machine, are let in);
* a cap on connected browsers: one more is refused (503);

and turns file uploads off (this viewer has no upload control; viser would buffer the parts).
"""

from __future__ import annotations

import http
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import viser
import websockets.asyncio.server as ws_server
from viser import _messages

#: Messages a browser may send at most (bytes): GUI changes and camera moves are a few hundred
#: bytes; a rendered image (``ClientHandle.get_render``) is the largest the viewer asks for.
MAX_MESSAGE = 4 * 1024 * 1024
MAX_QUEUE = 4
MAX_CLIENTS = 8
UPLOADS = (_messages.FileTransferStartUpload, _messages.FileTransferPart)

_patching = threading.Lock()


LOOPBACK = ("127.0.0.1", "localhost", "::1")
#: hosts that listen on every interface, loopback included
WILDCARD = ("0.0.0.0", "::", "")


def origins(host: str, port: int, extra: tuple[str, ...] = ()) -> list[str | None]:
    """The Origins a page of this viewer has, ``extra`` ones (``ADVISOR_VIEWER_ORIGINS``:
    another name or port it is reached by, e.g. a port Docker publishes it on), and none (a
    program, not a page). Its own: the address it listens on, and the loopback names when it
    listens on loopback or on every interface (``0.0.0.0``, ``::``: a page at
    ``http://127.0.0.1:<port>`` is then this viewer's own, as Docker publishes it on the
    host's loopback). A page of any other origin is refused (403)."""
    names = set()
    if host in LOOPBACK or host in WILDCARD:
        names |= {"127.0.0.1", "localhost", "[::1]"}
    if host not in WILDCARD:
        names.add(f"[{host}]" if ":" in host else host)
    own = [f"http://{name}:{port}" for name in sorted(names)]
    return [*own, *(o for o in extra if o not in own), None]


@contextmanager
def _bounded_serve(max_message: int, max_clients: int, extra: tuple[str, ...]) -> Iterator[None]:
    """While viser starts, its call of ``websockets.asyncio.server.serve`` gets the bounds."""
    original = ws_server.serve

    def serve(handler: Callable[..., Any], host: str, port: int, **kwargs: Any) -> Any:
        live = 0

        async def counted(connection: Any) -> None:
            nonlocal live
            live += 1
            try:
                await handler(connection)
            finally:
                live -= 1

        inner = kwargs.get("process_request")

        def process_request(connection: Any, request: Any) -> Any:
            upgrade = request.headers.get("Upgrade", "").lower() == "websocket"
            if upgrade and live >= max_clients:
                return connection.respond(
                    http.HTTPStatus.SERVICE_UNAVAILABLE,
                    f"the viewer serves at most {max_clients} browsers at once\n",
                )
            return inner(connection, request) if inner is not None else None

        kwargs |= {
            "max_size": max_message,
            "max_queue": MAX_QUEUE,
            "origins": origins(host, port, extra),
            "process_request": process_request,
        }
        return original(counted, host, port, **kwargs)

    with _patching:
        setattr(ws_server, "serve", serve)  # noqa: B010  (a class: mypy would refuse)
        try:
            yield
        finally:
            setattr(ws_server, "serve", original)  # noqa: B010


def bounded_server(
    host: str, port: int, max_message: int = MAX_MESSAGE, max_clients: int = MAX_CLIENTS,
    extra_origins: tuple[str, ...] = (),
) -> viser.ViserServer:  # fmt: skip
    """A viser server on ``host:port`` (or the next free port) with the bounds above."""
    with _bounded_serve(max_message, max_clients, extra_origins):
        server = viser.ViserServer(host=host, port=port, verbose=False)
    no_uploads(server._websock_server)
    return server


def no_uploads(interface: Any) -> None:
    """Drop file-upload messages instead of buffering them (``interface``: the server's or one
    client's websocket interface; each GUI registers its own handlers)."""
    for message in UPLOADS:
        if message in interface._incoming_handlers:
            interface.unregister_handler(message)


def client_without_uploads(client: viser.ClientHandle) -> None:
    """:func:`no_uploads` for a client's own GUI (``client.gui``)."""
    no_uploads(client._websock_connection)
