"""Bounded work per connection: what one caller's open sockets may cost the API.

uvicorn alone keeps a connection as long as its peer likes while the TLS handshake or the
request's headers are unfinished (asyncio's 60 s handshake default, no header or read timeout
at all), and any one address may hold as many of them as it opens. Here:

- a per-address cap (`per_address`): a peer's connection beyond it is dropped at once, before
  its TLS handshake costs anything (counted from the TCP accept, so unfinished handshakes count);
- the TLS handshake must finish within `tls_handshake_timeout_s`;
- a request's headers must be complete within `header_timeout_s` of its first byte (or of
  the connection, for the first request); a slow-header client is cut off, however it trickles;
- while a request's body is coming, no more than `read_timeout_s` of silence.

TLS is therefore done here, around uvicorn's own HTTP protocol (asyncio's SSLProtocol, with
the handshake timeout uvicorn does not pass on), rather than by uvicorn's `ssl_*` options.
"""

from __future__ import annotations

import asyncio
import logging
import ssl
from asyncio.sslproto import SSLProtocol
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from ares.core.config import Params, param

log = logging.getLogger(__name__)


class ConnectionSettings(Params):
    """What one caller's connections may hold: a cap per address, and how long each phase may take."""

    per_address: int = param(32, "open connections per peer address; more are dropped at accept", ge=1)
    tls_handshake_timeout_s: float = param(5.0, "a TLS handshake unfinished this long is dropped", unit="s", gt=0)
    header_timeout_s: float = param(
        5.0, "a request's headers must be complete this long after its first byte", unit="s", gt=0
    )
    read_timeout_s: float = param(10.0, "most silence while a request's body is still coming", unit="s", gt=0)


class AddressLedger:
    """Open connections per peer address (one per server: the event loop is its only user)."""

    def __init__(self, per_address: int):
        self.per_address = per_address
        self.open: Counter[str] = Counter()

    def admit(self, address: str) -> bool:
        if self.open[address] >= self.per_address:
            return False
        self.open[address] += 1
        return True

    def release(self, address: str) -> None:
        self.open[address] -= 1
        if self.open[address] <= 0:
            del self.open[address]


def peer_address(transport: asyncio.BaseTransport) -> str:
    peer = transport.get_extra_info("peername")
    return str(peer[0]) if isinstance(peer, tuple) and peer else "unknown"


class _Admission:
    """The cap, at the outermost protocol's accept: `admitted` is the address counted, if any."""

    ledger: AddressLedger
    admitted: str | None = None

    def _admit(self, transport: asyncio.BaseTransport) -> bool:
        address = peer_address(transport)
        if not self.ledger.admit(address):
            log.warning("REST API: %s holds %d connections already: dropped one more", address, self.ledger.per_address)
            transport.abort()  # type: ignore[attr-defined]
            return False
        self.admitted = address
        return True

    def _release(self) -> None:
        if self.admitted is not None:
            self.ledger.release(self.admitted)
            self.admitted = None


class TimedHttpProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a header timeout and a body read timeout."""

    settings: ConnectionSettings

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._deadline: asyncio.TimerHandle | None = None
        self._reading_body = False

    def _arm(self, seconds: float) -> None:
        self._disarm()
        self._deadline = self.loop.call_later(seconds, self._too_slow)

    def _disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _too_slow(self) -> None:
        self._deadline = None
        if not self.transport.is_closing():
            log.info("REST API: %s too slow to send its request: closed", self.client[0] if self.client else "?")
            self.transport.close()

    def _between_requests(self) -> bool:
        return self.cycle is None or self.cycle.response_complete

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm(self.settings.header_timeout_s)

    def data_received(self, data: bytes) -> None:
        # a new request's first bytes start its header clock (keep-alive had no clock of ours)
        if self._deadline is None and not self._reading_body and self._between_requests():
            self._arm(self.settings.header_timeout_s)
        elif self._reading_body:
            self._arm(self.settings.read_timeout_s)
        super().data_received(data)

    def on_headers_complete(self) -> None:
        super().on_headers_complete()
        self._reading_body = True
        self._arm(self.settings.read_timeout_s)

    def on_message_complete(self) -> None:
        self._reading_body = False
        self._disarm()
        super().on_message_complete()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)


class AdmittedHttpProtocol(_Admission, TimedHttpProtocol):
    """Plain HTTP (--insecure-http): the cap at the HTTP protocol itself."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        if self._admit(transport):
            super().connection_made(transport)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.admitted is None:
            return  # dropped at accept: uvicorn never saw it
        self._release()
        super().connection_lost(exc)


class AdmittedTlsProtocol(_Admission, SSLProtocol):
    """TLS around the timed HTTP protocol: the cap before the handshake, the handshake timed."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if self._admit(transport):
            super().connection_made(transport)

    def connection_lost(self, exc: BaseException | None) -> None:
        if self.admitted is None:
            return
        self._release()
        super().connection_lost(exc)


def server_tls_context(cert: Path, key: Path) -> ssl.SSLContext:
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.load_cert_chain(str(cert), str(key))
    return context


def protocol_factory(settings: ConnectionSettings, tls: ssl.SSLContext | None) -> Callable[..., asyncio.BaseProtocol]:
    """What uvicorn calls (as its `http` protocol class) for each accepted connection."""
    ledger = AddressLedger(settings.per_address)
    timed = type("TimedHttp", (TimedHttpProtocol,), {"settings": settings})
    if tls is None:
        return type("AdmittedHttp", (AdmittedHttpProtocol,), {"settings": settings, "ledger": ledger})

    def tls_protocol(**uvicorn_args: Any) -> asyncio.BaseProtocol:
        loop = uvicorn_args.get("_loop") or asyncio.get_event_loop()
        protocol = AdmittedTlsProtocol(
            loop,
            timed(**uvicorn_args),
            tls,
            None,  # type: ignore[arg-type]  # no waiter: as asyncio's own servers, nobody awaits the handshake
            server_side=True,
            ssl_handshake_timeout=settings.tls_handshake_timeout_s,  # type: ignore[arg-type]  # seconds, any float
        )
        protocol.ledger = ledger
        return protocol

    return tls_protocol
