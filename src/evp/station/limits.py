"""Limits that keep one hostile or broken client from starving the others (issue 34).

- Connections: at most ``station.max_connections`` open, ``max_connections_per_client`` from one
  address. A full station makes room by closing the oldest connection that is still waiting for
  its request headers (a slow or idle client), never one that is streaming or an operator's
  live feed; only when there is none is the newcomer refused. A connection must complete its
  headers within ``header_timeout_s``. (Under TLS a client that never finishes the handshake is
  not seen here yet; asyncio drops it after its 60 s handshake timeout.)
- Request bodies: refused (413) beyond ``max_body_bytes`` before they are read.
- Logs: the same message at most ``log_burst`` times per ``log_window_s`` (an accept-error storm
  once grew the log by 147 MB in 40 s); then one line says how many were held back.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

from starlette.responses import JSONResponse

from evp.config import StationSettings


@dataclass(frozen=True)
class OpenConnection:
    """What admission needs to know of an open connection."""

    client: str  # remote address
    waiting: bool  # no request under way: still reading headers, or idle between requests
    accepted_at: float
    handle: object = None


def admission(others: list[OpenConnection], client: str, max_total: int, max_per_client: int) -> tuple[bool, OpenConnection | None]:
    """(admit the newcomer from ``client``?, the connection to close first to make room)."""
    same = [c for c in others if c.client == client]
    if len(others) >= max_total:
        pool = others
    elif len(same) >= max_per_client:
        pool = same
    else:
        return True, None
    waiting = [c for c in pool if c.waiting]
    if not waiting:
        return False, None
    return True, min(waiting, key=lambda c: c.accepted_at)


def guarded_http_protocol(settings: StationSettings, clock: Callable[[], float] = time.monotonic):
    """uvicorn's h11 protocol with the connection limits and the header timeout (``http=`` of
    uvicorn's Config). WebSocket connections keep counting after their upgrade: uvicorn's
    connection set holds them too."""
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class GuardedH11Protocol(H11Protocol):
        accepted_at = 0.0
        _deadline = None

        def connection_made(self, transport) -> None:
            super().connection_made(transport)
            self.accepted_at = clock()
            others = [_describe(c) for c in self.connections if c is not self]
            admit, victim = admission(others, self._address(), settings.max_connections, settings.max_connections_per_client)
            if victim is not None:
                victim.handle.transport.abort()
            if not admit:
                transport.abort()
                return
            self._deadline = self.loop.call_later(settings.header_timeout_s, self._headers_overdue)

        def _address(self) -> str:
            return self.client[0] if self.client else ""

        def waiting(self) -> bool:
            return self.cycle is None or self.cycle.response_complete

        def _headers_overdue(self) -> None:
            if self.transport.is_closing():  # closed meanwhile (a closed TLS transport has no protocol left to ask)
                return
            upgraded = self.transport.get_protocol() is not self  # a WebSocket now: not ours to time out
            if self.cycle is None and not upgraded:
                self.transport.abort()

        def connection_lost(self, exc) -> None:
            if self._deadline is not None:
                self._deadline.cancel()
            super().connection_lost(exc)

    def _describe(connection) -> OpenConnection:
        waiting = connection.waiting() if isinstance(connection, GuardedH11Protocol) else False  # upgraded: a live WebSocket
        client = connection.client[0] if getattr(connection, "client", None) else ""
        return OpenConnection(client, waiting, getattr(connection, "accepted_at", 0.0), connection)

    return GuardedH11Protocol


def dead_link_aware_websocket_protocol(silence_s: float):
    """uvicorn's WebSocket protocol with another rule for its ping timeout: a link is dead when
    nothing at all came from it for ``silence_s`` (station.heartbeat_timeout_s), pongs or
    anything else. A pong that is merely late (it waits behind the phone's own frames, or a
    busy machine ran the phone late) does not cut a healthy link. A dead link is dropped at
    once: uvicorn closes it politely, and over TLS that waits for the peer's close_notify, which
    a dead peer never sends (asyncio gives up after 30 s)."""
    from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

    class DeadLinkAwareProtocol(WebSocketsSansIOProtocol):
        heard_at = 0.0

        def data_received(self, data: bytes) -> None:
            self.heard_at = self.loop.time()
            super().data_received(data)

        def keepalive_timeout(self) -> None:
            silent_s = self.loop.time() - self.heard_at
            if silent_s < silence_s:
                self.pong_timer = self.loop.call_later(silence_s - silent_s, self.keepalive_timeout)
                return
            super().keepalive_timeout()
            self.transport.abort()

    return DeadLinkAwareProtocol


class BodyLimit:
    """ASGI middleware: a body over ``max_bytes`` is refused with 413, by its Content-Length
    before a byte of it is read, or as soon as a chunked body passes the limit."""

    def __init__(self, app, max_bytes: int):
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = dict(scope.get("headers", [])).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_bytes):
            await self._too_large(scope, receive, send)
            return
        received = 0
        started = False

        async def counted_receive():
            nonlocal received
            message = await receive()
            received += len(message.get("body", b""))
            if received > self.max_bytes:
                raise _TooLarge
            return message

        async def watched_send(message):
            nonlocal started
            started = True
            await send(message)

        try:
            await self.app(scope, counted_receive, watched_send)
        except _TooLarge:
            if not started:
                await self._too_large(scope, receive, send)

    async def _too_large(self, scope, receive, send) -> None:
        response = JSONResponse({"error": f"request body over {self.max_bytes} bytes"}, status_code=413, headers={"Connection": "close"})
        await response(scope, receive, send)


class _TooLarge(Exception):
    pass


class RateLimitedLog(logging.Filter):
    """A filter that passes the same message (logger and format string) at most ``burst`` times
    per ``window_s``; the first one after a window that held some back says how many."""

    def __init__(self, burst: int, window_s: float, clock: Callable[[], float] = time.monotonic):
        super().__init__()
        self.burst, self.window_s, self.clock = burst, window_s, clock
        self._windows: dict[tuple[str, str], list] = {}  # key -> [window start, passed, held back]

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, str(record.msg)[:200])
        now = self.clock()
        window = self._windows.get(key)
        if window is None or now - window[0] >= self.window_s:
            held = window[2] if window is not None else 0
            self._windows[key] = [now, 1, 0]
            if len(self._windows) > 1000:  # messages that vary in their format string: keep the newest
                self._windows = {key: self._windows[key]}
            if held:
                record.msg = f"{record.msg} [{held} more like this held back in the last {self.window_s:g} s]"
            return True
        if window[1] < self.burst:
            window[1] += 1
            return True
        window[2] += 1
        return False


class FailureThrottle:
    """Failed attempts per client over the last ``window_s``: a client with ``max_failures`` of
    them is :meth:`blocked` until the oldest leaves the window. Holds at most ``max_clients``
    clients (the ones seen longest ago are forgotten first), so a flood from many addresses
    cannot grow it."""

    def __init__(self, max_failures: int, window_s: float, clock: Callable[[], float] = time.monotonic, max_clients: int = 10_000):
        self.max_failures, self.window_s, self.clock, self.max_clients = max_failures, window_s, clock, max_clients
        self._failures: dict[str, list[float]] = {}  # client -> failure times, oldest first (insertion order: least recent client first)

    def _recent(self, client: str) -> list[float]:
        times = [t for t in self._failures.get(client, ()) if self.clock() - t < self.window_s]
        if times:
            self._failures[client] = times
        else:
            self._failures.pop(client, None)
        return times

    def blocked(self, client: str) -> float:
        """Seconds until ``client`` may try again (0: now)."""
        times = self._recent(client)
        return self.window_s - (self.clock() - times[0]) if len(times) >= self.max_failures else 0.0

    def failed(self, client: str) -> bool:
        """Count a failure; True when it is the one that blocks the client (tell it once)."""
        times = self._recent(client)
        times.append(self.clock())
        self._failures.pop(client, None)
        self._failures[client] = times  # now the most recent client
        while len(self._failures) > self.max_clients:
            del self._failures[next(iter(self._failures))]
        return len(times) == self.max_failures


LIMITED_LOGGERS = ("asyncio", "uvicorn", "uvicorn.error", "evp")


def limit_logs(settings: StationSettings) -> RateLimitedLog:
    """Install one rate limit on the loggers a flood reaches (asyncio's accept errors, uvicorn's
    protocol errors, the station's own)."""
    limit = RateLimitedLog(settings.log_burst, settings.log_window_s)
    for name in LIMITED_LOGGERS:
        logging.getLogger(name).addFilter(limit)
    return limit
