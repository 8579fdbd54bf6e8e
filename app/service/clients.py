"""Who a request comes from, for per-client session quotas (docs/ACCESS.md).

A client is the key it sends, where it is one the service knows, else its address: the peer's
address, or, for a request from a proxy the operator trusts (``ADVISOR_TRUSTED_PROXIES``), the
last address of ``X-Forwarded-For`` that is not such a proxy (each proxy appends the address it
got the request from, so the addresses left of the first untrusted one are whatever the client
wrote). uvicorn's own reading of forwarded headers is off (``serve``): it would trust any
``X-Forwarded-For`` from 127.0.0.1.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Sequence

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


def trusted(address: str, among: Sequence[Network]) -> bool:
    """Whether ``address`` is in one of the networks ``among`` (not if it is no address)."""
    if not among:
        return False
    try:
        ip = ipaddress.ip_address(address)
    except ValueError:
        return False
    return any(ip in net for net in among)


def client_address(conn: HTTPConnection, proxies: Sequence[Network]) -> str:
    """The client's address: the peer's, or behind trusted proxies the forwarded one."""
    peer = conn.client.host if conn.client else "unknown"
    if not proxies or not trusted(peer, proxies):
        return peer
    hops = [h.strip() for v in conn.headers.getlist("x-forwarded-for") for h in v.split(",")]
    for hop in reversed(hops):
        if hop and not trusted(hop, proxies):
            return hop
    return peer
