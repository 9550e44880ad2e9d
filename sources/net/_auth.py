"""Shared-secret admission of a TCP sender (``?secret=`` or the
``TECTUM_NET_SECRET`` environment variable, on both ends).

On accepting a connection the receiver sends a CHALLENGE (type 5: the
44-byte header with ``n`` = 16, then 16 random bytes: the nonce). The
sender answers, before anything else, with AUTH (type 6: the header with its
``session`` and ``n`` = 32, then HMAC-SHA256 of ``"tectum-net-auth-1" |
nonce | session u32`` under the secret). Both travel framed like every TCP
message (u32 length first).

What it protects: only a holder of the secret becomes a sender, so a peer
without it cannot fix the stream's sensor and columns, move its time, end
the run with a forged END or take the one sender's place; a recorded AUTH
is worth nothing on another connection (a fresh nonce each time). What it
does not: the stream is neither encrypted nor authenticated message by
message, so anyone on the path can read it, and an attacker able to inject
into the TCP connection itself (on the path, with its sequence numbers)
can alter it; peers without the secret still take a connection slot until
their first message is due (``timeout_s``). UDP has no secret (datagrams
cannot be bound to a handshake): its sender is the first address and
session whose message is valid.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import struct

from ._wire import HEADER, _header

__all__ = ["CHALLENGE", "AUTH", "NONCE", "TAG", "secret_of", "challenge", "auth", "nonce_of", "check"]

CHALLENGE, AUTH = 5, 6
NONCE, TAG = 16, 32
ENV = "TECTUM_NET_SECRET"
_CONTEXT = b"tectum-net-auth-1"


def secret_of(param: str) -> bytes:
    """The secret from the parameter, else from ``TECTUM_NET_SECRET`` (b"": none)."""
    return (param or os.environ.get(ENV, "")).encode("utf-8")


def challenge() -> tuple[bytes, bytes]:
    """(nonce, the CHALLENGE message)."""
    nonce = os.urandom(NONCE)
    return nonce, _header(CHALLENGE, 0, 0, 0, 0, 0, 0, NONCE) + nonce


def nonce_of(msg: bytes) -> bytes | None:
    """The nonce of a CHALLENGE message, None if it is not one."""
    if len(msg) != HEADER + NONCE or msg[:2] != b"TQ" or msg[3] != CHALLENGE:
        return None
    return msg[HEADER:]


def _tag(secret: bytes, nonce: bytes, session: int) -> bytes:
    return hmac.new(secret, _CONTEXT + nonce + struct.pack("<I", session & 0xFFFFFFFF), hashlib.sha256).digest()


def auth(secret: bytes, nonce: bytes, session: int) -> bytes:
    """The AUTH message answering ``nonce`` for ``session``."""
    return _header(AUTH, session, 0, 0, 0, 0, 0, TAG) + _tag(secret, nonce, session)


def check(secret: bytes, nonce: bytes, msg: bytes) -> bool:
    """True when ``msg`` is an AUTH message with the right tag."""
    if len(msg) != HEADER + TAG or msg[:2] != b"TQ" or msg[3] != AUTH:
        return False
    session = struct.unpack_from("<I", msg, 4)[0]
    return hmac.compare_digest(msg[HEADER:], _tag(secret, nonce, session))
