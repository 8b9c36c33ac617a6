"""Connection guards of the HTTP server: slow clients are closed, no client set can hold every socket.

uvicorn closes idle keep-alive connections but waits forever for a request's
headers and for a slow body. `guarded_protocol(settings)` is uvicorn's h11
protocol with these rules added per connection:

- the request headers must be complete `header_timeout_s` after the connection
  (or the request's first byte) arrived, else `408` and close;
- a body in progress may pause at most `body_timeout_s` between chunks, must
  average at least `body_min_rate` bytes/s once `body_grace_s` have passed
  (as Apache's mod_reqtimeout `body=grace,MinRate=rate`: each `body_min_rate`
  bytes buy one more second), and the whole request (headers and body) must be
  in within `request_deadline_s` of its first byte; else `408` (when nothing
  was answered yet) and close. Time the application spends not reading (its
  buffer full) is not counted against the client;
- at most `max_per_client` open connections per client address; past it a new
  connection gets `503` and is closed at once;
- at most `max_connections` open connections in all: near it (the last 1/32, at
  least 2, are a reserve) a new connection closes the connection that has waited
  longest for its request headers (a half-open or idle keep-alive one, answered
  `503`) and takes its place; when every connection is busy with a request it
  takes a reserve place, where a request whose body is still to come gets `503`
  (bodiless ones, `/healthz`, or one whose body came whole with its headers are
  served); past the cap it gets `503` and is closed at once.
  So a flood of half-open connections never exhausts the file descriptors, and
  neither it nor a flood of slow bodies keeps `/healthz` from being answered.

`CloseUnreadBodies`, an ASGI middleware, makes a response sent before its
request's body was read whole (a `401`, `403`, `413`, `429`, any early error)
carry `Connection: close`: uvicorn then closes the connection after the
response instead of reading the rest of the body.

`RateLimitedLog` keeps a flood of identical log lines (a connection storm, "Too
many open files") from filling the disk: a few per interval, then a count.

uvicorn internals used here (uvicorn has no public hook for these rules): the
subclassed `H11Protocol` and its attributes `conn` (the h11 connection: whose
turn it is), `flow.read_paused`, `transport`, `client` and `loop`, and the
methods `connection_made`, `connection_lost`, `data_received` and
`on_response_complete` it extends.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import resource
import time
from typing import TYPE_CHECKING

import h11
from starlette.types import ASGIApp, Receive, Scope, Send
from uvicorn.protocols.http.h11_impl import H11Protocol

if TYPE_CHECKING:
    from .settings import Settings

log = logging.getLogger("wosac_server.guard")

# File descriptors kept out of the connection cap's reach besides the accept bursts (`accept_backlog`):
# the listening socket, the database, log files, worker pipes.
FD_RESERVE = 64
MAX_AUTO_CONNECTIONS = 8192


def _open_files_limit() -> int:
    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    return 1 << 20 if soft == resource.RLIM_INFINITY else soft


def accept_backlog(open_files: int | None = None) -> int:
    """uvicorn's `backlog`: the kernel's queue of connections not yet accepted, and how many asyncio
    accepts in one go before any is refused (each a descriptor meanwhile): a quarter of the open-file
    limit, at least 64, at most uvicorn's default 2048. A short queue drops the SYNs of a burst (the
    client retries after a second), a long one needs the descriptors free."""
    open_files = _open_files_limit() if open_files is None else open_files
    return max(64, min(2048, open_files // 4))


def connection_limit(max_connections: int, open_files: int | None = None) -> int:
    """The global cap on open connections: `max_connections` when set (> 0), else sized from the
    open-file limit: half of what is left after `FD_RESERVE` and two accept bursts (asyncio may accept a
    second before the first is refused; every connection may also hold an upload's file), at most
    `MAX_AUTO_CONNECTIONS`. An explicit value is lowered to what the limit allows."""
    open_files = _open_files_limit() if open_files is None else open_files
    room = max(8, (open_files - FD_RESERVE - 2 * accept_backlog(open_files)) // 2)
    if max_connections > 0:
        return min(max_connections, room)
    return min(room, MAX_AUTO_CONNECTIONS)


def _plain_response(status: str, text: str) -> bytes:
    body = text.encode()
    return (
        f"HTTP/1.1 {status}\r\ncontent-type: text/plain; charset=utf-8\r\ncontent-length: {len(body)}\r\n"
        "connection: close\r\n\r\n"
    ).encode() + body


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with header and body deadlines, a body rate, and connection caps."""

    header_timeout_s = 10.0
    body_timeout_s = 60.0
    body_grace_s = 20.0
    body_min_rate = 500.0  # bytes/s; 0: no rate rule
    request_deadline_s = 3600.0
    max_per_client = 32
    max_connections = 1000
    open_per_client: collections.Counter = collections.Counter()
    open_connections: set = set()
    waiting: dict = {}  # connections waiting for request headers -> since when, oldest first

    # uvicorn's H11Protocol narrows asyncio's BaseTransport to Transport the same way (and says so likewise).
    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._watch: asyncio.TimerHandle | None = None
        self._counted = False
        self._host = self.client[0] if self.client else ""
        if self.open_per_client[self._host] >= self.max_per_client:
            log.warning("refused a connection from %s: over %d open connections", self._host, self.max_per_client)
            self._refuse(f"too many open connections from this address (limit {self.max_per_client})\n")
            return
        self._reserve = False
        reserve = max(2, self.max_connections // 32)  # kept for bodiless requests (/healthz) when all are busy
        if len(self.open_connections) >= self.max_connections - reserve:
            oldest = next(iter(self.waiting), None)
            if oldest is not None:
                log.warning(
                    "closed the connection from %s that waited longest for a request: the server holds %d connections",
                    oldest._host,
                    len(self.open_connections),
                )
                oldest._refuse("the server is at its connection limit and closed this idle connection\n")
            elif len(self.open_connections) < self.max_connections:
                self._reserve = True  # may ask only for what has no body
            else:
                log.warning(
                    "refused a connection from %s: the server holds %d connections, none idle",
                    self._host,
                    self.max_connections,
                )
                self._refuse("the server is at its connection limit; retry shortly\n")
                return
        self._counted = True
        self.open_per_client[self._host] += 1
        self.open_connections.add(self)
        self._await_request()

    def connection_lost(self, exc: Exception | None) -> None:
        self._forget()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        before = self.conn.their_state
        super().data_received(data)
        state, now = self.conn.their_state, time.monotonic()
        if before is h11.IDLE and self._request_start is None:
            self._request_start = now  # a request's first byte: its deadline runs from here
        if state is h11.SEND_BODY:
            self.waiting.pop(self, None)
            if self._reserve and before is not h11.SEND_BODY:
                log.warning("refused a request with a body from %s: every connection is busy", self._host)
                self._refuse("the server is at its connection limit; retry shortly\n")
                return
            if before is not h11.SEND_BODY:  # the headers are in: the body's clock starts
                self._body_start, self._body_bytes, self._last_data, self._last_check = now, 0, now, now
                self._check()
            else:
                self._body_bytes += len(data)
                self._last_data = now
        elif state is h11.IDLE:
            if before is not h11.IDLE:  # a pipelined request began
                self._await_request()
        else:
            self.waiting.pop(self, None)
            self._disarm()  # the request is in: the application's time is not limited here

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing() and self.conn.their_state is h11.IDLE:
            self._await_request()  # idle keep-alive: uvicorn's own timeout closes it, or the cap does

    # -- the rules --------------------------------------------------------------------------------
    def _await_request(self) -> None:
        """Waiting for a request's headers: evictable by the cap, and its header deadline runs."""
        if not self._counted:
            return
        self.waiting.pop(self, None)
        now = time.monotonic()
        self.waiting[self] = now
        self._request_start = None
        self._headers_due = now + self.header_timeout_s
        self._arm(self.header_timeout_s)

    def _refuse(self, text: str) -> None:
        self._forget()
        if not self.transport.is_closing():
            self.transport.write(_plain_response("503 Service Unavailable", text))
            self.transport.close()

    def _forget(self) -> None:
        self._disarm()
        self.waiting.pop(self, None)
        if self._counted:
            self._counted = False
            self.open_connections.discard(self)
            self.open_per_client[self._host] -= 1
            if self.open_per_client[self._host] <= 0:
                del self.open_per_client[self._host]

    def _arm(self, seconds: float) -> None:
        self._disarm()
        self._watch = self.loop.call_later(max(0.0, seconds), self._check)

    def _disarm(self) -> None:
        if self._watch is not None:
            self._watch.cancel()
            self._watch = None

    def _body_due(self, now: float) -> tuple[float, str]:
        """When the body in progress breaks a rule, and which."""
        dues = [(self._last_data + self.body_timeout_s, f"its body paused for {self.body_timeout_s:g} s")]
        if self.body_min_rate > 0:
            dues.append(
                (
                    self._body_start + self.body_grace_s + self._body_bytes / self.body_min_rate,
                    f"its body came slower than {self.body_min_rate:g} bytes/s",
                )
            )
        start = self._request_start if self._request_start is not None else self._body_start
        dues.append((start + self.request_deadline_s, f"the request took over {self.request_deadline_s:g} s"))
        return min(dues)

    def _check(self) -> None:
        self._watch = None
        if self.transport.is_closing():
            return
        now = time.monotonic()
        state = self.conn.their_state
        if state is h11.SEND_BODY:
            if self.flow.read_paused:  # the application is not reading: not the client's fault
                paused = now - self._last_check
                self._body_start += paused
                self._last_data = max(self._last_data, now)
                if self._request_start is not None:
                    self._request_start += paused
                self._last_check = now
                self._arm(1.0)
                return
            self._last_check = now
            due, why = self._body_due(now)
            if now < due:
                self._arm(due - now)
                return
            log.warning("closed a connection from %s: %s", self._host, why)
            if self.conn.our_state in (h11.IDLE, h11.SEND_RESPONSE):  # nothing answered yet
                self.transport.write(_plain_response("408 Request Timeout", f"the request was too slow: {why}\n"))
            self.transport.close()
        elif state is h11.IDLE:
            if now < self._headers_due:
                self._arm(self._headers_due - now)
                return
            log.warning(
                "closed a connection from %s: no complete request headers within %g s",
                self._host,
                self.header_timeout_s,
            )
            self.transport.write(_plain_response("408 Request Timeout", "request headers took too long\n"))
            self.transport.close()

    _last_check = 0.0
    _reserve = False
    _request_start: float | None = None
    _headers_due = 0.0


class CloseUnreadBodies:
    """ASGI middleware: a response that starts before its request's body was read whole carries
    `Connection: close`, so uvicorn closes the connection once it is sent rather than reading (and
    waiting for) the rest of a body nobody wants."""

    def __init__(self, app: ASGIApp):
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = dict(scope["headers"])
        body_done = b"chunked" not in headers.get(b"transfer-encoding", b"").lower() and headers.get(
            b"content-length", b"0"
        ).strip() in (b"0", b"")

        async def tracked_receive():
            nonlocal body_done
            message = await receive()
            if message["type"] == "http.request" and not message.get("more_body", False):
                body_done = True
            return message

        async def closing_send(message):
            if message["type"] == "http.response.start" and not body_done:
                kept = [(k, v) for k, v in message.get("headers", []) if k.lower() != b"connection"]
                message = {**message, "headers": [*kept, (b"connection", b"close")]}
            await send(message)

        return await self.app(scope, tracked_receive, closing_send)


def guarded_protocol(settings: Settings) -> type[GuardedH11Protocol]:
    """The protocol class for uvicorn's `http=`, with the service's limits (call it after the open-file
    limit is raised: the connection cap is sized from it)."""
    return type(
        "ServiceH11Protocol",
        (GuardedH11Protocol,),
        {
            "header_timeout_s": settings.header_timeout_s,
            "body_timeout_s": settings.body_timeout_s,
            "body_grace_s": settings.body_grace_s,
            "body_min_rate": settings.body_min_rate,
            "request_deadline_s": settings.request_deadline_s,
            "max_per_client": settings.max_connections_per_client,
            "max_connections": connection_limit(settings.max_connections),
            "open_per_client": collections.Counter(),
            "open_connections": set(),
            "waiting": {},
        },
    )


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
