"""The HTTP the upload client needs, on the standard library alone: one request per connection,
bodies streamed from a file, the server's `{"detail": ...}` read out, and retries with backoff.

One connection per request keeps every failure local to its request: a connection the server closed
after an early answer, or one left half-written by an interruption, is never reused.
"""

from __future__ import annotations

import contextlib
import dataclasses
import email.utils
import http.client
import json
import os
import random
import socket
import ssl
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, BinaryIO, Protocol
from urllib.parse import quote, urlencode, urlsplit

from wosac_eval import __version__

USER_AGENT = f"wosac-eval/{__version__}"
# Answers worth asking again: a timeout of ours, quotas and rate limits, the server's own failures,
# its proxies', and a full disk.
RETRYABLE_STATUS = frozenset({408, 429, 500, 502, 503, 504, 507})


class SubmitError(Exception):
    """The submission could not be made or followed; the message says why, in one sentence."""


class SubmissionRefused(SubmitError):
    """The server refused a request (4xx): `status` and its one-sentence reason, `detail`."""

    def __init__(self, status: int, detail: str, hint: str = "") -> None:
        self.status = status
        self.detail = detail
        super().__init__(f"the server refused it ({status}): {detail}{hint}")


class SubmissionFailed(SubmitError):
    """The job ended `failed`; `status` is its final status (`error`, `validation_report`)."""

    def __init__(self, status: dict) -> None:
        self.status = status
        super().__init__(f"submission {status['id']} failed: {status.get('error') or 'no reason given'}")


class ServerUnavailable(SubmitError):
    """The server could not be reached, or kept failing (5xx, 507), past the retry budget."""


class ProtocolError(SubmitError):
    """The server answered something this client does not understand (is the URL a wosac-server?)."""


class AnswerTooSlow(ServerUnavailable):
    """An answer that did not come whole within its deadline (a server trickling a few bytes a second)."""


# A downloaded answer (the result document) may take this long per byte of its Content-Length besides the
# request's own deadline: at least 256 KiB/s, a few minutes for a validation-size result of ~150 MB.
DOWNLOAD_S_PER_BYTE = 1 / (256 * 1024)


@dataclass(frozen=True)
class RetryPolicy:
    """How long one request is retried before giving up.

    Delays grow exponentially from `base_s` to at most `cap_s`, each drawn in its upper half
    ("equal jitter", so clients restarted together do not come back together); a `Retry-After`
    header is honoured instead. `attempts` tries, and at most `max_wait_s` of waiting, per request;
    any progress (a chunk stored) starts the count again.
    """

    attempts: int = 10
    base_s: float = 0.5
    cap_s: float = 30.0
    max_wait_s: float = 900.0
    first_contact_attempts: int = 3  # a server that never answered in this run (a wrong URL?) is given up sooner
    answer_deadline_s: float = 120.0  # a status or result answer must come whole within this (not retried)

    def delay(self, failures: int, retry_after: float | None) -> float:
        if retry_after is not None:
            return retry_after + random.uniform(0, min(1.0, 0.1 * retry_after))
        step = min(self.cap_s, self.base_s * 2 ** (failures - 1))
        return step / 2 + random.uniform(0, step / 2)


@dataclass
class Response:
    status: int
    headers: dict[str, str]  # names lower-case
    body: bytes

    def json(self) -> dict:
        try:
            value = json.loads(self.body)
        except ValueError:
            value = None
        if not isinstance(value, dict):
            raise ProtocolError(
                f"the server answered {self.status} with {_snippet(self.body)!r}, not a JSON "
                "object; is the URL a wosac-server?"
            )
        return value

    def detail(self) -> str:
        """The server's reason: its JSON `detail` (a validation error's list joined), else the body's start."""
        try:
            detail = json.loads(self.body).get("detail")
        except (ValueError, AttributeError):
            detail = None
        if isinstance(detail, list):  # FastAPI's parameter validation: [{"loc": [...], "msg": ...}, ...]
            parts = []
            for item in detail:
                if isinstance(item, dict):
                    where = ".".join(str(p) for p in item.get("loc", [])[1:])
                    parts.append(f"{where}: {item.get('msg')}" if where else str(item.get("msg")))
            detail = "; ".join(parts)
        if detail:
            return str(detail)
        return _snippet(self.body) or http.client.responses.get(self.status, "no reason given")

    def retry_after(self) -> float | None:
        value = self.headers.get("retry-after")
        if value is None:
            return None
        try:
            return max(0.0, float(value))
        except ValueError:
            pass
        try:
            return max(0.0, email.utils.parsedate_to_datetime(value).timestamp() - time.time())
        except (TypeError, ValueError, IndexError):
            return None

    def offset(self) -> int | None:
        value = self.headers.get("upload-offset")
        return int(value) if value is not None and value.isdigit() else None


def _snippet(body: bytes) -> str:
    return body[:200].decode("utf-8", "replace").strip()


def network_error_text(error: BaseException) -> str:
    if isinstance(error, socket.timeout):
        return "the connection timed out"
    if isinstance(error, ConnectionRefusedError):
        return "connection refused"
    if isinstance(error, (ConnectionResetError, BrokenPipeError, http.client.RemoteDisconnected)):
        return "the connection was closed"
    return f"{type(error).__name__}: {error}"


# What a dropped, refused or timed-out connection raises: retried. (ssl.SSLCertVerificationError is an
# OSError too, but no retry fixes a certificate: it is raised at once.)
NETWORK_ERRORS = (OSError, http.client.HTTPException)


@dataclass
class Server:
    """A wosac-server: its base URL (a path prefix is kept) and the key sent with every request."""

    url: str
    key: str = field(repr=False)
    timeout: float = 60.0  # seconds a connection may stay silent
    deadline_s: float = 120.0  # seconds a bodiless request's whole answer may take, however it trickles
    answered: bool = field(default=False, init=False)  # any answer in this run: the URL is right

    def __post_init__(self) -> None:
        parts = urlsplit(self.url.strip())
        host = parts.hostname
        if parts.scheme not in ("http", "https") or not host:
            raise ValueError(f"server URL {self.url!r}: give http://HOST[:PORT] or https://HOST[:PORT]")
        try:
            parts.port  # noqa: B018 - raises on a bad port
        except ValueError as error:
            raise ValueError(f"server URL {self.url!r}: {error}") from None
        self._parts = parts
        self._host = host
        self.url = f"{parts.scheme}://{parts.netloc}{parts.path.rstrip('/')}"

    def path(self, route: str, query: dict | None = None) -> str:
        prefix = self._parts.path.rstrip("/")
        text = prefix + "/v1/" + "/".join(quote(p, safe="") for p in route.split("/"))
        if query:
            text += "?" + urlencode({k: _query_value(v) for k, v in query.items() if v is not None})
        return text

    def _connection(self, timeout: float | None) -> http.client.HTTPConnection:
        host, port = self._host, self._parts.port
        if self._parts.scheme == "https":
            return http.client.HTTPSConnection(host, port, timeout=timeout, context=ssl.create_default_context())
        return http.client.HTTPConnection(host, port, timeout=timeout)

    def request(
        self,
        method: str,
        path: str,
        headers: dict[str, str] | None = None,
        body: Iterable[bytes] | None = None,
        body_length: int = 0,
        timeout: float | None = None,
        sink: BinaryIO | None = None,
        deadline: float | None = None,
    ) -> Response:
        """One request on a fresh connection; raises one of NETWORK_ERRORS when no answer came back.

        A server may answer before it has read the body (401, 413, 429: then it closes the
        connection): when sending fails, the answer is still read if it arrived. With `sink`, a 200
        answer's body is written there a block at a time (the Response's body is then empty); a body
        that ends before its Content-Length raises http.client.IncompleteRead. With `deadline`, the whole
        exchange must end within that many seconds (a sink's within that plus its Content-Length at
        256 KiB/s), else AnswerTooSlow: a server that trickles its answer never holds the client.
        """
        conn = self._connection(self.timeout if timeout is None else timeout)
        watchdog = _Watchdog(deadline)
        try:
            conn.connect()
            watchdog.sock = conn.sock  # the connection lets go of it once the answer's headers are read
            answer = self._exchange(conn, method, path, headers, body, body_length)
            self.answered = True
            if sink is not None and answer.status == 200:
                length = answer.getheader("content-length")
                if length is not None and length.isdigit():
                    watchdog.extend(int(length) * DOWNLOAD_S_PER_BYTE)
                while block := answer.read1(2**20):
                    sink.write(block)
                if answer.length:  # http.client counts what a Content-Length still promised
                    raise http.client.IncompleteRead(b"", answer.length)
                data = b""
            else:
                data = answer.read()
            watchdog.check(method, path)
            return Response(answer.status, {k.lower(): v for k, v in answer.getheaders()}, data)
        except NETWORK_ERRORS:
            watchdog.check(method, path)
            raise
        finally:
            watchdog.stop()
            conn.close()

    def _exchange(
        self,
        conn: http.client.HTTPConnection,
        method: str,
        path: str,
        headers: dict[str, str] | None,
        body: Iterable[bytes] | None,
        body_length: int,
    ) -> http.client.HTTPResponse:
        """Send the request; its answer's status and headers read."""
        sent = {
            "User-Agent": USER_AGENT,
            "Authorization": f"Bearer {self.key}",
            "Connection": "close",
            **(headers or {}),
        }
        if body is not None or method in ("POST", "PUT", "PATCH"):
            sent["Content-Length"] = str(body_length)
        try:
            conn.putrequest(method, path, skip_accept_encoding=True)
            for name, value in sent.items():
                conn.putheader(name, value)
            conn.endheaders()
            for piece in body or ():
                conn.send(piece)
        except (BrokenPipeError, ConnectionResetError) as send_error:
            try:
                return conn.getresponse()
            except NETWORK_ERRORS:
                raise send_error from None
        return conn.getresponse()


class _Watchdog:
    """Ends a connection whose exchange outlives its deadline (its socket shut down: a blocked read returns),
    and says so as AnswerTooSlow."""

    def __init__(self, deadline: float | None) -> None:
        self.deadline, self.fired = deadline, threading.Event()
        self.sock: socket.socket | None = None
        self.started = time.monotonic()
        self.timer: threading.Timer | None = None
        if deadline is not None:
            self._arm(deadline)

    def _arm(self, seconds: float) -> None:
        self.timer = threading.Timer(max(0.0, seconds), self._fire)
        self.timer.daemon = True
        self.timer.start()

    def _fire(self) -> None:
        self.fired.set()
        sock = self.sock
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)

    def extend(self, seconds: float) -> None:
        """More time for a body whose length is known now."""
        if self.timer is None or self.deadline is None:
            return
        self.timer.cancel()
        self.deadline += seconds
        self._arm(self.deadline - (time.monotonic() - self.started))

    def check(self, method: str, path: str) -> None:
        if self.fired.is_set():
            raise AnswerTooSlow(
                f"{method} {path}: the server's answer did not come whole within {self.deadline:.0f} s (it "
                "sends too slowly); the server or the network to it is at fault: try again later"
            )

    def stop(self) -> None:
        if self.timer is not None:
            self.timer.cancel()


def _query_value(value: Any) -> str:
    return ("true" if value else "false") if isinstance(value, bool) else str(value)


class Retrier:
    """Counts the failures of one request (or of a run of chunks without progress) against a policy."""

    def __init__(
        self, policy: RetryPolicy, log: Callable[[str], None], sleep: Callable[[float], None] = time.sleep
    ) -> None:
        self.policy, self.log, self.sleep = policy, log, sleep
        self.reset()

    def reset(self) -> None:
        self.failures = 0
        self.waited = 0.0

    def wait(self, what: str, reason: str, retry_after: float | None = None, refusal: int | None = None) -> None:
        """Sleep before the next try, saying why. Once the policy's tries or waiting time are spent, or a
        Retry-After asks for more than is left, raise ServerUnavailable, or SubmissionRefused(refusal)
        when the answer was the server's refusal (429: a quota, a rate limit)."""
        self.failures += 1
        delay = self.policy.delay(self.failures, retry_after)
        left = self.policy.max_wait_s - self.waited
        if self.failures >= self.policy.attempts or delay > left:
            if retry_after is not None and delay > left:
                why = f"the server asks to retry in {retry_after:.0f} s"
            else:
                why = f"gave up after {self.failures} tries over {self.waited:.0f} s"
            if refusal is not None:
                raise SubmissionRefused(refusal, f"{reason} ({why})")
            raise ServerUnavailable(f"{what}: {reason} ({why})")
        self.log(f"{what}: {reason}; retrying in {delay:.1f} s (try {self.failures + 1} of {self.policy.attempts})")
        self.sleep(delay)
        self.waited += delay

    def call(
        self,
        server: Server,
        what: str,
        send: Callable[[], Response],
        ok: Callable[[Response], bool] = lambda r: r.status < 400,
        reset: bool = True,
    ) -> Response:
        """`send()` until it answers something that is not worth retrying (network errors, RETRYABLE_STATUS
        retried); returns that answer, successful or not: the caller reads refusals. `reset=False` goes on
        counting the failures before it (a resync after a failed chunk shares the chunk's budget)."""
        if reset:
            self.reset()
        while True:
            try:
                answer = send()
            except NETWORK_ERRORS as error:
                self.network_failure(server, what, error)
                continue
            if ok(answer) or answer.status not in RETRYABLE_STATUS:
                return answer
            self.wait(what, *status_reason(answer))

    def network_failure(self, server: Server, what: str, error: BaseException) -> None:
        """Wait after a request that got no answer, or raise: at once for a certificate or a host name that
        does not resolve, sooner while the server has not answered once in this run."""
        if isinstance(error, ssl.SSLCertVerificationError):
            raise ServerUnavailable(f"{what}: {server.url}: the server's certificate is not trusted ({error})")
        if isinstance(error, socket.gaierror):
            raise ServerUnavailable(f"{what}: cannot resolve the host name of {server.url} ({error.strerror or error})")
        if not server.answered and self.failures + 1 >= self.policy.first_contact_attempts:
            raise ServerUnavailable(
                f"{what}: cannot reach {server.url} ({network_error_text(error)}, "
                f"{self.failures + 1} tries); is the URL right and the server up?"
            )
        self.wait(what, f"server unreachable ({network_error_text(error)})")


def status_reason(answer: Response) -> tuple[str, float | None, int | None]:
    """(reason, Retry-After, refusal status) of a retryable answer, as Retrier.wait takes them."""
    if answer.status == 429:  # a quota or rate limit: in the end, the server's refusal with its reason
        return answer.detail(), answer.retry_after(), 429
    return f"{answer.status} {answer.detail()}", answer.retry_after(), None


KEY_ENV = "WOSAC_API_KEY"


class ArgumentError(ValueError):
    """A bad argument of `submit`, found before anything is sent."""


def api_key(key: str | None) -> str:
    key = key if key is not None else os.environ.get(KEY_ENV)
    if not key:
        raise ArgumentError(f"no API key: pass key=... or set {KEY_ENV}")
    if any(c.isspace() for c in key) or not key.isprintable():
        raise ArgumentError("the API key holds spaces or control characters; copy it again")
    return key


class CallOwner(Protocol):
    """What `call` asks of the object it requests for (a `tus.Sender`, a `following.Follower`)."""

    @property
    def server(self) -> Server: ...
    @property
    def policy(self) -> RetryPolicy: ...
    @property
    def log(self) -> Callable[[str], None]: ...


def call(
    owner: CallOwner,
    what: str,
    method: str,
    route: str,
    query: dict | None = None,
    headers: dict[str, str] | None = None,
    retrier: Retrier | None = None,
    deadline: float | None = None,
) -> Response:
    """One bodiless request, retried by `owner`'s policy (or `retrier`, counting on from its failures); the
    answer that was not worth retrying. Its answer must come whole within `deadline` (default: the
    server's `deadline_s`)."""
    server = owner.server
    return (retrier or Retrier(owner.policy, owner.log)).call(
        server,
        what,
        lambda: server.request(method, server.path(route, query), headers, deadline=deadline or server.deadline_s),
        reset=retrier is None,
    )


def refused(answer: Response) -> SubmitError:
    if 400 <= answer.status < 500:
        return SubmissionRefused(answer.status, answer.detail())
    return ProtocolError(f"unexpected answer {answer.status}: {answer.detail()}")


def required(value: dict, fields: dict[str, type | tuple[type, ...]], what: str) -> dict:
    """`value` (a JSON object the server sent) once it holds each of `fields` with a value of its type; else
    ProtocolError naming what is missing: the server's fault, not this client's."""
    wrong = [name for name, kind in fields.items() if not isinstance(value.get(name), kind) or value.get(name) is True]
    if wrong:
        shown = ", ".join(
            f"{name!r} ({'missing' if name not in value else type(value[name]).__name__})" for name in wrong
        )
        raise ProtocolError(
            f"the server's answer to {what} lacks {shown}: it is not a wosac-server's answer (the server is at "
            "fault, not this client; its operator can tell why)"
        )
    return value


def options_with(kind: type, given: Any, fields: dict) -> Any:
    """`given` (an options dataclass of `kind`, or None) with `fields` replacing its fields.

    Raises:
      ArgumentError: a field `kind` does not have, or a required one missing (naming it).
    """
    try:
        return dataclasses.replace(given, **fields) if given is not None else kind(**fields)
    except TypeError as error:
        raise ArgumentError(f"{kind.__name__}: {error}") from None
