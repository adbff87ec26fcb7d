"""The live page's trust boundary: who may connect, which files the page may name, what its
messages may show.

The page is a websocket client; without a check any web page open in the user's browser (a
foreign origin) or any program that can reach the port could steer the characters, probe the
file system through the "BVH path" field, switch the run folder and learn into it. So:

* **Connections** (:class:`Admission`): a websocket handshake is accepted only when its ``Origin``
  is the page's own address and its ``Host`` header names the address served (loopback names for
  ``127.0.0.1``/``localhost``; on every interface, ``0.0.0.0``, Origin and Host must agree, which
  refuses other sites but not DNS rebinding, hence the token). With a token
  (``jaxstyle play --token``) the page must also connect to ``ws://HOST:PORT/<token>``, which the
  URL printed at start does (``?websocket=``, viser's own parameter). A refused handshake is
  closed (code 1008) before any of its messages is read, and logged.
* **Paths** (:func:`confine`): a file or folder named in the page is resolved (``..`` and
  symbolic links followed) and must lie under one of the allowed roots; the check runs before
  anything looks at the file, and the refusal is the same whether or not the path exists.
* **Where** (:class:`Serving`, :func:`check_address`): the host and port served, the token, and
  a host that is not an address of this machine refused at once.
* **Messages** (:func:`without_content`): errors about a file the page named are shown with
  any quoted excerpt of the file removed, so a refusal never reads a file out to the page.

viser (1.1) has no hook for the handshake's headers; :func:`install` registers a connect
callback on viser's websocket server and reads the handshake from its live connections. If a
viser version lacks them, :func:`install` raises instead of serving unguarded.
"""

from __future__ import annotations

import asyncio
import dataclasses
import hmac
import ipaddress
import os
import re
from pathlib import Path
from typing import Callable, Iterable
from urllib.parse import urlsplit

from jaxstyle.play.models import PlayError

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")
EVERY_INTERFACE = ("0.0.0.0", "::", "")


@dataclasses.dataclass(frozen=True)
class Admission:
    """Which websocket handshakes the server at ``host:port`` accepts (see the module docstring)."""

    host: str
    port: int
    token: str | None = None

    @property
    def every_interface(self) -> bool:
        return self.host in EVERY_INTERFACE

    def names(self) -> tuple[str, ...]:
        """The host names the page may be reached by (``()``: any, on every interface)."""
        if self.every_interface:
            return ()
        if _is_loopback(self.host):
            return LOOPBACK_NAMES
        return (f"[{self.host}]" if ":" in self.host else self.host,)

    def refusal(self, headers, path: str) -> str | None:
        """Why a handshake with these ``headers`` (a mapping; ``Host``, ``Origin``) to ``path`` is
        refused, or None to accept it."""
        host = (headers.get("Host") or "").strip().lower()
        origin = (headers.get("Origin") or "").strip().lower()
        if not host:
            return "no Host header"
        if not origin:
            return "no Origin header (only the page may connect)"
        parts = urlsplit(origin)
        if (parts.scheme not in ("http", "https") or not parts.netloc or parts.path not in ("", "/")
                or parts.query or parts.fragment):  # an Origin is scheme://host[:port], nothing more
            return f"foreign origin {origin!r}"
        origin_host = parts.netloc if parts.port else f"{parts.netloc}:{80 if parts.scheme == 'http' else 443}"
        allowed = {f"{name}:{self.port}" for name in self.names()}
        if allowed:
            if host not in allowed:
                return f"Host {host!r} is not this server ({', '.join(sorted(allowed))})"
            if origin_host not in allowed:
                return f"foreign origin {origin!r}"
        else:
            if not host.endswith(f":{self.port}"):
                return f"Host {host!r} is not this server's port {self.port}"
            if origin_host != host:
                return f"foreign origin {origin!r} (the page is {host!r})"
        if self.token is not None:
            given = path.split("?", 1)[0].strip("/")
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return "no valid token (open the URL printed by `jaxstyle play`)"
        return None

    def page_url(self, shown_host: str | None = None) -> str:
        """The URL to open: ``http://HOST:PORT`` (with the token, viser's ``?websocket=``
        parameter pointing the page's connection at ``ws://HOST:PORT/<token>``)."""
        host = shown_host or ("localhost" if self.every_interface else self.host)
        host = f"[{host}]" if ":" in host and not host.startswith("[") else host
        base = f"http://{host}:{self.port}"
        return base if self.token is None else f"{base}/?websocket=ws://{host}:{self.port}/{self.token}"


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def install(viser_server, admission: Admission, log: Callable[[str], None]) -> None:
    """Refuse every websocket connection of ``viser_server`` that ``admission`` refuses, those
    already open included (closed with code 1008 before their messages are read)."""
    try:
        ws = viser_server._websock_server
        live = ws._live_connections
        loop = ws._background_event_loop
        register = ws.on_client_connect
    except AttributeError as e:  # another viser: serving without the check is not an option
        raise PlayError(f"this viser version does not expose its websocket handshakes ({e}); jaxstyle play "
                        "cannot check who connects and will not serve (viser 1.1 does)") from None

    def refusal(connection) -> str | None:
        try:
            request = connection.request
            return admission.refusal(request.headers, request.path)
        except AttributeError:
            return "no handshake to check"

    async def guard(conn) -> None:
        connection = live.get(conn.client_id)
        reason = "no handshake to check" if connection is None else refusal(connection)
        if reason is not None:
            log(f"refused a connection: {reason}")
            if connection is not None:
                await connection.close(1008, "refused by jaxstyle play")

    register(guard)
    for connection in list(live.values()):  # any that connected before the guard was in place
        reason = refusal(connection)
        if reason is not None and loop is not None:
            log(f"refused a connection: {reason}")
            asyncio.run_coroutine_threadsafe(connection.close(1008, "refused by jaxstyle play"), loop)


def confine(path: str | os.PathLike, roots: Iterable[Path], what: str = "file") -> Path:
    """``path`` resolved, if it lies under one of ``roots``; else a PlayError that names the
    roots but says nothing about ``path`` itself (whether it exists, what it is)."""
    roots = [Path(r).resolve() for r in roots]
    text = str(path).strip()
    if not text:
        raise PlayError(f"give the path of a {what}")
    refusal = PlayError(f"the page may only name a {what} under {', '.join(str(r) for r in roots)}; "
                        f"{text} is not read")
    try:
        resolved = Path(text).expanduser().resolve()
    except (ValueError, OSError, RuntimeError):  # a NUL byte, ~nosuchuser, a symlink loop
        raise refusal from None
    if not any(resolved == r or r in resolved.parents for r in roots):
        raise refusal
    return resolved


_QUOTED = re.compile(r"'[^'\n]*'|\"[^\"\n]*\"")


def without_content(message: str) -> str:
    """``message`` with every quoted excerpt replaced by ``'…'`` (what a file holds is not shown
    to the page)."""
    return _QUOTED.sub("'…'", message)


@dataclasses.dataclass(frozen=True)
class Serving:
    """Where the page is served: ``host`` and ``port`` (0: a free port, read back as
    :attr:`jaxstyle.play.server.PlayServer.port` once started), the ``token`` a browser must present (``None``: none;
    :mod:`jaxstyle.play.guard`) and ``verbose`` (viser's own log)."""

    host: str = "127.0.0.1"
    port: int = 8080
    token: str | None = None
    verbose: bool = False


def check_address(host: str) -> None:
    """A PlayError unless ``host`` is an address of this machine to serve on (viser's server
    waits forever on a name it cannot look up or bind)."""
    import socket

    try:
        infos = socket.getaddrinfo(host.strip("[]") or None, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (OSError, UnicodeError) as e:
        raise PlayError(f"--host {host}: not an address or known host name ({getattr(e, 'strerror', None) or e})") \
            from None
    family, kind, proto, _, address = infos[0]
    try:
        with socket.socket(family, kind, proto) as probe:
            probe.bind(address)
    except OSError as e:
        raise PlayError(f"--host {host}: not an address of this machine ({e.strerror or e})") from None
