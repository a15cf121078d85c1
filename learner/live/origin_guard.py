"""Which web pages may open the studio's websocket: its own, and those named with
`--allow-origin`. Every other page is refused at the handshake (HTTP 403), before any scene data.

Why: a browser lets any page it shows open a websocket to 127.0.0.1; the page's origin rides in
the `Origin` header and the server must check it (websockets have no same-origin policy). On
main, a foreign page received the studio's scene stream and could drive its controls.

The rule, per handshake:
    no Origin header     accepted: not a browser (a browser always sends one), and a local program
                         can reach the socket anyway;
    Origin allow-listed  accepted (`--allow-origin http://host:port`, for use from other machines);
    same origin          accepted when the Origin is `http://<Host header>` and that host is an
                         IP literal or `localhost`: the studio's own page however it was reached
                         (127.0.0.1, [::1], this machine's address). A DNS name is not enough,
                         since a rebound name (DNS rebinding) would pass as same-origin;
    anything else        refused, 403, counted in `refused`.

How: viser (1.x) builds its `websockets.asyncio.server.serve` inside its server thread and takes
no origin option, so `guarded_viser_server` hands it, for the duration of the constructor only, a
`serve` that runs this check before viser's own request hook. If a viser release stops calling
`serve` there, construction fails ("the origin check could not be installed") rather than
serving unchecked.
"""

from __future__ import annotations

import collections
import contextlib
import ipaddress
import threading
from typing import Any, Iterable
from urllib.parse import urlsplit

import viser
import websockets.asyncio.server as ws_server


def parse_origin(value: str, flag: str = "--allow-origin") -> str:
    """`scheme://host[:port]` (http or https, no path) in the form browsers send; ValueError
    with one line naming `flag` otherwise."""
    try:
        parts = urlsplit(value.strip())
        port = parts.port
    except ValueError as exc:
        raise ValueError(f"{flag} {value!r}: {exc}; give an origin such as http://myhost:8080") from None
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"{flag} {value!r} is not an origin; give scheme://host[:port] with scheme http or https, "
                         "e.g. http://myhost:8080")
    if parts.path not in ("", "/") or parts.query or parts.fragment or parts.username or parts.password:
        raise ValueError(f"{flag} {value!r}: an origin has no path, query or user; give scheme://host[:port]")
    host = parts.hostname
    if ":" in host:
        host = f"[{host}]"
    default = {"http": 80, "https": 443}[parts.scheme]
    return f"{parts.scheme}://{host}" + (f":{port}" if port is not None and port != default else "")


def _literal_or_localhost(host: str) -> bool:
    if host.lower() == "localhost":
        return True
    try:
        ipaddress.ip_address(host.strip("[]"))
        return True
    except ValueError:
        return False


class OriginPolicy:
    """The check above; `allowed` are origins as `parse_origin` returns them."""

    def __init__(self, allowed: Iterable[str] = ()):
        self.allowed = frozenset(parse_origin(o) for o in allowed)
        self.refused: collections.Counter[str] = collections.Counter()
        """Refused handshakes by Origin (at most `MAX_TRACKED` distinct ones, then "other")."""

    MAX_TRACKED = 64

    def allows(self, origin: str | None, host: str | None) -> bool:
        if origin is None:
            return True
        try:
            origin = parse_origin(origin, "Origin")
        except ValueError:
            return False
        if origin in self.allowed:
            return True
        if not host:
            return False
        try:  # the page's own origin as the browser names it: http:// and the Host header it sent
            expected = parse_origin(f"http://{host}", "Host")
        except ValueError:
            return False
        return origin == expected and _literal_or_localhost(urlsplit(expected).hostname or "")

    def _count(self, origin: str) -> None:
        key = origin if origin in self.refused or len(self.refused) < self.MAX_TRACKED else "other"
        self.refused[key] += 1

    def wrap(self, process_request):
        """A websockets `process_request` that refuses foreign websocket handshakes with 403 and
        hands everything else to `process_request` (viser's page server, or None)."""

        def check(connection, request):
            headers = request.headers
            if headers.get("Upgrade", "").lower() == "websocket" and not self.allows(headers.get("Origin"), headers.get("Host")):
                self._count(headers.get("Origin", "")[:200])
                return connection.respond(403, "the studio accepts websockets from its own page only (see --allow-origin)\n")
            return process_request(connection, request) if process_request is not None else None

        return check


_SERVE_LOCK = threading.Lock()
"""One guarded construction at a time: `serve` is swapped module-wide while it runs."""


@contextlib.contextmanager
def _guarded_serve(policy: OriginPolicy):
    original = ws_server.serve
    installed: list[bool] = []

    class serve(original):  # noqa: N801 - stands in for websockets' own `serve` class
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            kwargs["process_request"] = policy.wrap(kwargs.get("process_request"))
            installed.append(True)
            super().__init__(*args, **kwargs)

    with _SERVE_LOCK:
        ws_server.serve = serve
        try:
            yield installed
        finally:
            ws_server.serve = original


def guarded_viser_server(policy: OriginPolicy, **kwargs: Any) -> viser.ViserServer:
    """A `viser.ViserServer(**kwargs)` whose websocket handshakes go through `policy`."""
    with _guarded_serve(policy) as installed:
        server = viser.ViserServer(**kwargs)
    if not installed:
        server.stop()
        raise RuntimeError("the origin check could not be installed in this viser version; refusing to serve unchecked")
    return server
