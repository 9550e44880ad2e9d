"""Parsing ``tcp://HOST:PORT`` and ``udp://HOST:PORT``."""

from __future__ import annotations

from urllib.parse import urlsplit


def parse(url: str) -> tuple[str, str, int]:
    """(scheme, host, port) of a ``tcp://`` or ``udp://`` URL."""
    u = urlsplit(url)
    if u.scheme not in ("tcp", "udp"):
        raise ValueError(f"{url!r}: expected tcp://HOST:PORT or udp://HOST:PORT")
    try:
        port = u.port
    except ValueError:
        port = None
    if not u.hostname or port is None:
        raise ValueError(f"{url!r}: expected {u.scheme}://HOST:PORT")
    return u.scheme, u.hostname, port
