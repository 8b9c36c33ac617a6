"""Connection guards of the HTTP server: slow clients are closed, one client cannot hold every socket.

uvicorn closes idle keep-alive connections but waits forever for a request's
headers and for a stalled body. `guarded_protocol(settings)` is uvicorn's h11
protocol with three rules added per connection:

- the request headers must be complete `header_timeout_s` after the connection
  (or the request's first byte) arrived, else `408` and close;
- a body in progress may pause at most `body_timeout_s` between chunks (unless
  the application is the one not reading), else the connection is closed;
- at most `max_connections_per_client` open connections per client address;
  past it a new connection gets `503` and is closed at once.

`RateLimitedLog` keeps a flood of identical log lines (a connection storm, "Too
many open files") from filling the disk: a few per interval, then a count.
"""
from __future__ import annotations

import collections
import logging
import time

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

log = logging.getLogger("wosac_server.guard")


def _plain_response(status: str, text: str) -> bytes:
    body = text.encode()
    return (f"HTTP/1.1 {status}\r\ncontent-type: text/plain; charset=utf-8\r\ncontent-length: {len(body)}\r\n"
            "connection: close\r\n\r\n").encode() + body


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with header and body timeouts and a per-client connection cap."""

    header_timeout_s = 10.0
    body_timeout_s = 60.0
    max_per_client = 32
    open_per_client: collections.Counter = collections.Counter()

    def connection_made(self, transport) -> None:  # noqa: ANN001 - asyncio's signature
        super().connection_made(transport)
        self._watch = None
        self._host = self.client[0] if self.client else ""
        self.open_per_client[self._host] += 1
        if self.open_per_client[self._host] > self.max_per_client:
            log.warning("refused a connection from %s: over %d open connections", self._host, self.max_per_client)
            transport.write(_plain_response("503 Service Unavailable",
                                            f"too many open connections from this address (limit "
                                            f"{self.max_per_client})\n"))
            transport.close()
            return
        self._arm(self.header_timeout_s)  # the first request's headers are due

    def connection_lost(self, exc) -> None:  # noqa: ANN001
        self._disarm()
        self.open_per_client[self._host] -= 1
        if self.open_per_client[self._host] <= 0:
            del self.open_per_client[self._host]
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        waiting_for_headers = self.conn.their_state is h11.IDLE
        super().data_received(data)
        state = self.conn.their_state
        if state is h11.SEND_BODY:
            self._arm(self.body_timeout_s)  # an idle timer: every chunk restarts it
        elif state is h11.IDLE:
            if not waiting_for_headers or self._watch is None:
                self._arm(self.header_timeout_s)  # a new request began: its headers are due
        else:
            self._disarm()  # the request is in: the application's time is not limited here

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._disarm()  # idle keep-alive: uvicorn's own timeout closes it

    def _arm(self, seconds: float) -> None:
        self._disarm()
        self._watch = self.loop.call_later(seconds, self._expired, time.monotonic())

    def _disarm(self) -> None:
        if self._watch is not None:
            self._watch.cancel()
            self._watch = None

    def _expired(self, armed_at: float) -> None:
        self._watch = None
        if self.transport.is_closing():
            return
        state = self.conn.their_state
        if state is h11.SEND_BODY:
            if self.flow.read_paused:  # the application is not reading: not the client's fault
                self._arm(self.body_timeout_s)
                return
            log.warning("closed a connection from %s: its body stalled for %g s", self._host, self.body_timeout_s)
            self.transport.close()
        elif state is h11.IDLE:
            log.warning("closed a connection from %s: no complete request headers within %g s", self._host,
                        self.header_timeout_s)
            self.transport.write(_plain_response("408 Request Timeout", "request headers took too long\n"))
            self.transport.close()


def guarded_protocol(settings) -> type[GuardedH11Protocol]:  # noqa: ANN001 - a Settings
    """The protocol class for uvicorn's `http=`, with the service's limits."""
    return type("ServiceH11Protocol", (GuardedH11Protocol,), {
        "header_timeout_s": settings.header_timeout_s, "body_timeout_s": settings.body_timeout_s,
        "max_per_client": settings.max_connections_per_client, "open_per_client": collections.Counter()})


class RateLimitedLog(logging.Filter):
    """At most `burst` records per `interval_s` for each message template; then one line counting the rest."""

    def __init__(self, burst: int = 5, interval_s: float = 10.0):
        super().__init__()
        self.burst, self.interval_s = burst, interval_s
        self.windows: dict[tuple, list] = {}  # (logger, template) -> [window start, records seen]

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, str(record.msg))
        now = time.monotonic()
        window = self.windows.get(key)
        if window is None or now - window[0] >= self.interval_s:
            suppressed = 0 if window is None else window[1] - self.burst
            if len(self.windows) > 1000:
                self.windows.clear()
            self.windows[key] = [now, 1]
            if suppressed > 0:
                record.msg = f"{record.msg} (and {suppressed} more like it in the last {self.interval_s:g} s)"
            return True
        window[1] += 1
        return window[1] <= self.burst


def install_log_limits(burst: int = 5, interval_s: float = 10.0) -> None:
    """Rate-limit every handler of the root logger and uvicorn's loggers."""
    limiter = RateLimitedLog(burst, interval_s)
    for name in ("", "uvicorn", "uvicorn.error", "uvicorn.access", "asyncio"):
        for handler in logging.getLogger(name).handlers:
            handler.addFilter(limiter)
