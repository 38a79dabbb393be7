"""Which hosts the service answers to, and which pages may change it: a guard against DNS
rebinding (a foreign name resolved to this server) and cross-site requests (a page elsewhere
posting to it).

A request whose ``Host`` is not in DACRT_ALLOWED_HOSTS is 403; unset, a request that arrives on a
loopback address (the server's own, or the bind address where the server does not say) must name
a loopback host, and one that arrives on another address may name any. A request other than GET
or HEAD that carries an ``Origin`` (browsers add it) is 403 unless that origin is the server's
own (its ``Host``) or one of DACRT_ALLOWED_HOSTS: the service sends no CORS headers, so no other
page should reach it. Clients that are not browsers send no ``Origin``.
"""

from __future__ import annotations

import ipaddress
import json
from urllib.parse import urlsplit

from starlette.datastructures import Headers

from .metrics import REFUSED_ROUTE

#: The names of this machine's loopback addresses, allowed when the server binds one.
LOOPBACK_HOSTS = ("localhost", "127.0.0.1", "::1")
#: Allows any host.
ANY_HOST = "*"
#: Methods a page may send elsewhere without changing anything.
SAFE_METHODS = ("GET", "HEAD")


def default_allowed_hosts(address: str) -> tuple[str, ...]:
    """The loopback names for a request that arrives on a loopback ``address``, else any host."""
    return LOOPBACK_HOSTS if is_loopback(address) else (ANY_HOST,)


def is_loopback(host: str) -> bool:
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def host_name(authority: str) -> str:
    """The host of ``host[:port]`` or ``[v6]:port``, lower case, without the port."""
    authority = authority.strip().lower()
    if authority.startswith("["):
        return authority[1 : authority.find("]")] if "]" in authority else authority
    return authority.rsplit(":", 1)[0] if authority.count(":") == 1 else authority


def origin_authority(origin: str) -> str:
    """``host[:port]`` of an ``Origin`` header, without its scheme's default port."""
    parts = urlsplit(origin.strip().lower())
    default = {"http": ":80", "https": ":443"}.get(parts.scheme, "")
    return parts.netloc.removesuffix(default) if default else parts.netloc


class HostCheck:
    """ASGI middleware: 403, before anything else runs, for a request to a host not in
    ``allowed`` (None: ``default_allowed_hosts`` of the address it arrives on, else of ``bind``)
    or an unsafe request from another origin."""

    def __init__(self, app, allowed: tuple[str, ...] | None, bind: str) -> None:
        self.app = app
        self.allowed = allowed
        self.bind = bind

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] == "http":
            problem = self.problem(scope)
            if problem is not None:
                scope[REFUSED_ROUTE] = True  # counted by the metrics under this label
                await refuse(send, problem)
                return
        await self.app(scope, receive, send)

    def problem(self, scope) -> str | None:
        """Why the request is refused, or None."""
        headers = Headers(scope=scope)
        host = headers.get("host", "")
        allowed = self.allowed
        if allowed is None:
            server = scope.get("server")  # the address the request arrived on
            allowed = default_allowed_hosts(server[0] if server else self.bind)
        if ANY_HOST not in allowed and host_name(host) not in allowed:
            return (
                f"Host {host!r} is not one this server answers to: it allows "
                f"{', '.join(allowed)} (DACRT_ALLOWED_HOSTS)"
            )
        origin = headers.get("origin")
        if origin is None or scope["method"] in SAFE_METHODS:
            return None
        authority = origin_authority(origin)
        own = authority == origin_authority(f"{scope.get('scheme', 'http')}://{host}")
        if own or ANY_HOST not in allowed and host_name(authority) in allowed:
            return None
        return (
            f"a {scope['method']} from the page of another origin ({origin}) is refused: this "
            "service answers its own pages and clients that send no Origin (DACRT_ALLOWED_HOSTS)"
        )


async def refuse(send, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", b"%d" % len(body))]
    await send({"type": "http.response.start", "status": 403, "headers": headers})
    await send({"type": "http.response.body", "body": body})
