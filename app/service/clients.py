"""Who a request comes from, for per-client session quotas (docs/ACCESS.md).

A client is the key it sends (``X-API-Key``), where it is one the service knows: the operator
key, or one of ``ADVISOR_CLIENT_KEYS`` (:class:`ClientKeys`). Otherwise (no key, or a key the
service does not know: anyone could invent keys) it is its address: the peer's address, or, for
a request from a proxy the operator trusts (``ADVISOR_TRUSTED_PROXIES``), the last address of
``X-Forwarded-For`` that is not such a proxy (each proxy appends the address it got the request
from, so the addresses left of the first untrusted one are whatever the client wrote). That
reading is uvicorn's ``ProxyHeadersMiddleware``, which ``create_app`` puts in front of the app
with the trusted proxies (:func:`trusted_hosts`) when there are some: it rewrites the request's
client (and its scheme from ``X-Forwarded-Proto``). uvicorn's own switch for it stays off
(``serve``): it would trust any ``X-Forwarded-For`` from 127.0.0.1.

Over MQTT (:mod:`app.service.mqtt`) a client is the device its topic names (the broker's ACL
makes it the publisher's user name): ``"mqtt <device>"`` (:func:`device_client`), a name no
HTTP client has (``"address ..."``, ``"key ..."``, ``"operator key"``).
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
from collections.abc import Iterable, Sequence

from starlette.requests import HTTPConnection

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def networks(entries: Sequence[str]) -> tuple[Network, ...]:
    """Addresses or CIDR networks; ValueError names an entry that is neither."""
    out = []
    for entry in entries:
        try:
            out.append(ipaddress.ip_network(entry.strip(), strict=False))
        except ValueError:
            raise ValueError(f"{entry!r} is not an IP address or network") from None
    return tuple(out)


def trusted_hosts(entries: Sequence[str]) -> list[str]:
    """The trusted proxies as uvicorn's ``ProxyHeadersMiddleware`` reads them: an address as
    an address, a network as its network (``10.0.0.5/24`` is ``10.0.0.0/24``: uvicorn would
    take a network with host bits for a name that matches nothing)."""
    return [
        str(n.network_address) if n.prefixlen == n.max_prefixlen else str(n)
        for n in networks(entries)
    ]


def trusted(address: str, among: Sequence[Network]) -> bool:
    """Whether ``address`` is in one of the networks ``among`` (not if it is no address)."""
    if not among:
        return False
    try:
        ip = ipaddress.ip_address(address)
    except ValueError:
        return False
    return any(ip in net for net in among)


def client_address(conn: HTTPConnection) -> str:
    """The client's address: the peer's, or behind trusted proxies the forwarded one (which
    uvicorn's ``ProxyHeadersMiddleware`` has made the request's client)."""
    return conn.client.host if conn.client else "unknown"


OPERATOR = "operator key"


def device_client(device: str) -> str:
    """The client of an MQTT device, for the quotas."""
    return f"mqtt {device}"


def _digest(key: str) -> bytes:
    return hashlib.sha256(key.encode()).digest()


class ClientKeys:
    """The keys that make a client of their own for the quotas, each with the name the quotas
    know it by (``"operator key"``, ``"key <name>"``): what Redis, the registry and a 429's
    detail hold is that name, never the key. Only the keys' SHA-256 digests are kept."""

    def __init__(self, named: Iterable[tuple[str, str]] = ()):
        self._entries = tuple((who, _digest(key)) for who, key in named)

    def __len__(self) -> int:
        return len(self._entries)

    def client(self, given: str) -> str | None:
        """The name of the client whose key ``given`` is (None: no known key). Every key is
        compared, in constant time, whichever matches."""
        got = _digest(given)
        found = None
        for who, digest in self._entries:
            if hmac.compare_digest(got, digest) and found is None:
                found = who
        return found
