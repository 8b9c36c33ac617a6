"""`submit`: send a submission to a wosac-server through its resumable uploads, and follow it to its result.

The file is sent in chunks (`PATCH /v1/uploads/{id}` at the offset the server holds), read a block
at a time, never whole. A dropped connection, a server restart, a 5xx, a full disk (`507`) or a rate
limit (`429`) is retried with exponential backoff (capped, jittered, `Retry-After` honoured) from
the offset the server reports (`HEAD`, or the `Upload-Offset` of a `409`). The upload's id is kept
in a small state file (see `state.py`), so running the same call again after any interruption (this
process killed, the network, the server) asks the server for its offset and goes on from there;
once complete, the file keeps the submission's id, and running it again follows that submission
instead of uploading the file again.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

from wosac_eval.client.following import Follower, Progress, no_progress
from wosac_eval.client.state import UploadState, default_state_dir, key_digest, prune
from wosac_eval.client.transport import (
    NETWORK_ERRORS,
    RETRYABLE_STATUS,
    ArgumentError,
    ProtocolError,
    Retrier,
    RetryPolicy,
    Server,
    ServerUnavailable,
    SubmissionRefused,
    SubmitError,
    api_key,
    call,
    refused,
    status_reason,
)

DEFAULT_CHUNK_BYTES = 64 * 2**20
BLOCK_BYTES = 2**20  # what is read from the file, and sent, at a time
CHALLENGES = ("sim_agents", "scenario_gen")

_logger = logging.getLogger("wosac_eval.client")


class _UploadGone(Exception):
    """The server no longer has the upload (404/410): expired, deleted, refused, or its bytes lost."""


def submit(
    submission: str | os.PathLike,
    *,
    server: str,
    key: str | None = None,
    method: str,
    challenge: str = "sim_agents",
    config: str | None = None,
    publish: bool = False,
    allow_partial: bool = False,
    wait: bool = False,
    output: str | os.PathLike | None = None,
    new: bool = False,
    chunk_bytes: int = DEFAULT_CHUNK_BYTES,
    limit_rate: int | None = None,
    progress: Progress | None = None,
    log: Callable[[str], None] | None = None,
    state_dir: str | os.PathLike | None = None,
    retry: RetryPolicy = RetryPolicy(),
    timeout: float = 60.0,
    poll_s: tuple[float, float] = (0.5, 5.0),
) -> dict:
    """Upload `submission` to the wosac-server at `server`, resumably; with `wait`, follow it to its result.

    Args:
      submission: the file (.tar.gz, .tar.bz2, .tar.xz, .tar, or one .binproto, optionally compressed).
      server: the service's base URL, e.g. "https://wosac.example.org".
      key: the API key (default: the WOSAC_API_KEY environment variable). Never written to disk.
      method: the leaderboard name. challenge, config, publish, allow_partial: as the server's
        upload parameters (config None: the challenge's current one).
      wait: follow the job until it is done or failed, and fetch its result.
      output: with `wait`, write the result document (the same JSON as `wosac-eval score`) there.
      new: forget an earlier upload of this file (an unfinished one is deleted on the server) and
        upload it again.
      chunk_bytes: bytes per PATCH request. limit_rate: at most this many bytes per second.
      progress: progress(stage, done, total), stage "upload" (bytes) or "scoring" (scenarios).
      log: called with one line per event (resumed, retrying, state changes); default: the
        "wosac_eval.client" logger at INFO.
      state_dir: where uploads are remembered (default $XDG_CACHE_HOME/wosac-eval/uploads, else
        ~/.cache/wosac-eval/uploads).
      retry: how long each request is retried (network errors, 5xx, 507, 429, 408).
      timeout: seconds a connection may stay silent. poll_s: the first and longest wait between
        two status requests while following the job.

    Returns:
      The submission's status (the server's JSON: id, state, progress, ...). With `wait`, its final
      status, with "result": the result's challenge, config, num_scenarios, coverage and buckets
      (realism_meta_metric, kinematic_metrics, interactive_metrics, map_based_metrics, min_ade).

    Raises:
      SubmissionRefused: the server refused a request (4xx); `.status`, `.detail` (its reason).
      SubmissionFailed: with `wait`, the job ended failed; `.status` holds its error.
      ServerUnavailable: unreachable, or failing (5xx, 507), past the retry budget; running the same
        call again resumes.
      SubmitError: anything else that stops it (the file changed while uploading, another run is
        uploading the same file, an answer that is not the service's).
      ValueError (ArgumentError): a bad argument (no key, a missing or empty file, a bad URL), before
        anything is sent.
    """
    run = _Run(
        submission,
        server=server,
        key=key,
        method=method,
        challenge=challenge,
        config=config,
        publish=publish,
        allow_partial=allow_partial,
        output=output,
        chunk_bytes=chunk_bytes,
        limit_rate=limit_rate,
        progress=progress,
        log=log,
        state_dir=state_dir,
        retry=retry,
        timeout=timeout,
        poll_s=poll_s,
    )
    return run.run(wait=wait, new=new)


class _Run:
    """One call of `submit`: the arguments checked, the state found, the upload resumed or started."""

    def __init__(
        self,
        submission,
        *,
        server,
        key,
        method,
        challenge,
        config,
        publish,
        allow_partial,
        output,
        chunk_bytes,
        limit_rate,
        progress,
        log,
        state_dir,
        retry,
        timeout,
        poll_s,
    ):
        if challenge not in CHALLENGES:
            raise ArgumentError(f"challenge {challenge!r}: choose {' or '.join(CHALLENGES)}")
        if not method or not str(method).strip():
            raise ArgumentError("give the method's leaderboard name (method=...)")
        if int(chunk_bytes) < 1:
            raise ArgumentError(f"chunk_bytes must be >= 1, not {chunk_bytes}")
        if limit_rate is not None and int(limit_rate) < 1:
            raise ArgumentError(f"limit_rate must be >= 1 byte per second, not {limit_rate}")
        self.file = Path(os.path.abspath(submission))
        if not self.file.exists():
            raise ArgumentError(f"{submission}: no such file")
        if not self.file.is_file():
            raise ArgumentError(
                f"{submission}: not a file; send the submission as one file (a folder of shards: "
                f"pack it first, e.g. tar czf {self.file.name}.tar.gz -C {self.file} .)"
            )
        stat = self.file.stat()
        if stat.st_size == 0:
            raise ArgumentError(f"{submission}: the file is empty")
        self.size, self.mtime_ns = stat.st_size, stat.st_mtime_ns
        self.key = api_key(key)
        try:
            self.server = Server(server, self.key, timeout)
        except ValueError as error:
            raise ArgumentError(str(error)) from None
        self.params = {
            "method": str(method),
            "challenge": challenge,
            "config": config,
            "publish": bool(publish),
            "allow_partial": bool(allow_partial),
        }
        self.output = output
        self.chunk = int(chunk_bytes)
        self.limit_rate = int(limit_rate) if limit_rate else None
        self.block = max(4096, min(BLOCK_BYTES, self.limit_rate // 20)) if self.limit_rate else BLOCK_BYTES
        self.progress = progress or no_progress
        self.log = log or _logger.info
        self.policy = retry
        self.follower = Follower(self.server, self.progress, self.log, retry, poll_s)
        folder = Path(state_dir) if state_dir is not None else default_state_dir()
        try:
            folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        except OSError as error:
            raise ArgumentError(f"state dir {folder}: cannot create it ({error.strerror or error})") from None
        if not os.access(folder, os.W_OK | os.X_OK):
            raise ArgumentError(f"state dir {folder}: not writable")
        prune(folder)
        self.state = UploadState(
            folder,
            {
                "server": self.server.url,
                "key": key_digest(self.key),
                "file": str(self.file),
                "size": self.size,
                "mtime_ns": self.mtime_ns,
                **self.params,
            },
        )
        self.sent = 0  # bytes sent in this run (a chunk sent again counts again)
        self.patches = 0  # PATCH requests answered in this run
        self.offset = 0  # the server's offset, as last known
        self._rate_start = None
        self._rate_bytes = 0

    # -- the run -----------------------------------------------------------------------------------------
    def run(self, *, wait: bool, new: bool) -> dict:
        self.state.load()
        if new:
            self._forget_earlier()
        status = self._earlier_submission()
        if status is None:
            with self.state.locked() as mine:
                if not mine:
                    raise SubmitError(
                        f"another wosac-eval submit is uploading {self.file} to {self.server.url} now "
                        f"(its lock: {self.state.lock_path}); let it finish, then run this again"
                    )
                self.state.load()  # the run that held the lock may have finished it
                try:
                    status = self._earlier_submission(quiet=True) or self._upload()
                except ServerUnavailable as error:
                    if self.state.data.get("upload_id"):
                        raise ServerUnavailable(
                            f"{error}; the server keeps upload {self.state.data['upload_id']}: "
                            "run the same command again to resume it"
                        ) from None
                    raise
        if not wait:
            return status
        try:
            return self.follower.follow(status["id"], status, self.output)
        except ServerUnavailable as error:
            raise ServerUnavailable(
                f"{error}; submission {status['id']} goes on at the server: run the same command again to follow it"
            ) from None

    def _forget_earlier(self) -> None:
        upload_id = self.state.data.get("upload_id")
        if upload_id and not self.state.data.get("submission_id"):
            with contextlib.suppress(*NETWORK_ERRORS):
                answer = self.server.request("DELETE", self.server.path(f"uploads/{upload_id}"))
                if answer.status == 204:
                    self.log(f"deleted the earlier unfinished upload {upload_id}")
        if self.state.data:
            self.state.forget()

    def _earlier_submission(self, quiet: bool = False) -> dict | None:
        """The status of the submission this file became in an earlier run, if the server still has it."""
        submission_id = self.state.data.get("submission_id")
        if not submission_id:
            return None
        status = self.follower.status(submission_id)
        if status is None:
            self.log(f"the server no longer has submission {submission_id} (uploaded earlier); uploading again")
            self.state.forget()
            return None
        if not quiet:
            self.log(
                f"{self.file.name} was uploaded before: submission {submission_id}, {status['state']} "
                "(--new uploads it again)"
            )
        return status

    def _upload(self) -> dict:
        for restart in range(3):
            try:
                return self._upload_once()
            except _UploadGone as gone:
                self.state.forget()
                if restart == 2:
                    raise SubmitError(f"{gone}, a third time; giving up") from None
                self.log(f"{gone}; starting a new upload")
        raise AssertionError("unreachable")

    def _upload_once(self) -> dict:
        upload_id = self.state.data.get("upload_id")
        if upload_id:
            self.offset = self._head(upload_id)
            self.log(
                f"resuming upload {upload_id} at byte {self.offset:,} of {self.size:,} "
                f"({self.offset / self.size:.0%}), the server's offset"
            )
            resumed_at = self.offset
        else:
            upload_id = self._create()
            self.offset = resumed_at = 0
        self.progress("upload", self.offset, self.size)
        try:
            while True:
                self._send(upload_id)
                self._check_unchanged(upload_id)
                status = self._complete(upload_id)
                if status is not None:
                    break
        except KeyboardInterrupt:
            self.log(
                f"upload {upload_id} interrupted at byte {self.offset:,} of {self.size:,}; the server keeps "
                "it (for 7 days by default): run the same command again to resume it"
            )
            raise
        resumed = f", resumed at byte {resumed_at:,}" if resumed_at else ""
        self.log(
            f"uploaded {self.file.name}: submission {status['id']}, {status['state']} "
            f"(sent {self.sent:,} bytes in {self.patches} PATCH request(s) in this run{resumed})"
        )
        return status

    # -- the protocol ------------------------------------------------------------------------------------
    def _create(self) -> str:
        answer = call(self, "creating the upload", "POST", "uploads", self.params, {"Upload-Length": str(self.size)})
        if answer.status != 201:
            raise refused(answer)
        upload_id = answer.json().get("upload_id")
        if not isinstance(upload_id, str) or not upload_id:
            raise ProtocolError("the server's answer to creating an upload holds no upload_id")
        self.state.save(
            upload_id=upload_id,
            submission_id=None,
            server=self.server.url,
            file=str(self.file),
            size=self.size,
            mtime_ns=self.mtime_ns,
            created_at=time.time(),
            **self.params,
        )
        self.log(f"upload {upload_id} created: {self.size:,} bytes to send in chunks of {self.chunk:,}")
        return upload_id

    def _head(self, upload_id: str, retrier: Retrier | None = None) -> int:
        """The offset the server holds; _UploadGone when it no longer has the upload."""
        answer = call(
            self, "asking the server for the upload's offset", "HEAD", f"uploads/{upload_id}", retrier=retrier
        )
        if answer.status in (404, 410):
            raise _UploadGone(
                f"the server no longer has upload {upload_id} ({answer.status}: expired, deleted, or its bytes lost)"
            )
        if answer.status != 200:
            raise refused(answer)
        declared = answer.headers.get("upload-length")
        if declared is not None and declared != str(self.size):
            raise _UploadGone(f"upload {upload_id} on the server was declared {declared} bytes long, not {self.size}")
        return self._checked_offset(answer.offset(), "HEAD")

    def _checked_offset(self, offset: int | None, what: str) -> int:
        if offset is None or not 0 <= offset <= self.size:
            raise ProtocolError(f"the server's {what} answer gives the offset {offset!r} for a {self.size}-byte upload")
        return offset

    def _send(self, upload_id: str) -> None:
        """PATCH chunks from self.offset to the end, resyncing to the server's offset after any failure."""
        path = self.server.path(f"uploads/{upload_id}")
        retrier = Retrier(self.policy, self.log)
        with open(self.file, "rb") as f:
            while self.offset < self.size:
                length = min(self.chunk, self.size - self.offset)
                headers = {"Upload-Offset": str(self.offset), "Content-Type": "application/offset+octet-stream"}
                try:
                    answer = self.server.request("PATCH", path, headers, self._pieces(f, self.offset, length), length)
                except NETWORK_ERRORS as error:
                    retrier.network_failure(self.server, "uploading", error)
                    self.offset = self._head(upload_id, retrier)  # a dropped PATCH's bytes that arrived are kept
                    self.progress("upload", self.offset, self.size)
                    continue
                else:
                    self.patches += 1
                    held = answer.offset()
                    if answer.status == 204:
                        self.offset = self._checked_offset(held, "PATCH")
                        retrier.reset()  # progress: the tries start again
                        continue
                    if answer.status in (404, 410):
                        raise _UploadGone(
                            f"the server no longer has upload {upload_id} ({answer.status}: {answer.detail()})"
                        )
                    if answer.status == 409 and held is not None and held != self.offset:
                        self.log(
                            f"the server holds {held:,} bytes of upload {upload_id}, not {self.offset:,}: "
                            "going on from there"
                        )
                        self.offset = self._checked_offset(held, "PATCH")
                        self.progress("upload", self.offset, self.size)
                        continue
                    if answer.status == 409:  # another request at work on it: an interrupted one, still being read
                        reason, retry_after, refusal = f"409 {answer.detail()}", answer.retry_after(), None
                    elif answer.status in RETRYABLE_STATUS:
                        reason, retry_after, refusal = status_reason(answer)
                    else:
                        raise refused(answer)
                self.progress("upload", self.offset, self.size)
                retrier.wait("uploading", reason, retry_after, refusal)
                self.offset = self._head(upload_id, retrier)
                self.progress("upload", self.offset, self.size)

    def _pieces(self, f, offset: int, length: int):
        """The chunk's bytes, a block at a time, paced to limit_rate; progress as they go."""
        f.seek(offset)
        done = 0
        while done < length:
            data = f.read(min(self.block, length - done))
            if not data:
                raise SubmitError(f"{self.file} got shorter while it was being uploaded")
            yield data
            done += len(data)
            self.sent += len(data)
            self.progress("upload", offset + done, self.size)
            if self.limit_rate:
                self._pace(len(data), self.limit_rate)

    def _pace(self, n: int, limit_rate: int) -> None:
        now = time.monotonic()
        if self._rate_start is None or now - self._rate_start > 10 + self._rate_bytes / limit_rate:
            self._rate_start, self._rate_bytes = now, 0  # (re)start after a long pause: no burst to catch up
        self._rate_bytes += n
        ahead = self._rate_bytes / limit_rate - (time.monotonic() - self._rate_start)
        if ahead > 0:
            time.sleep(ahead)

    def _check_unchanged(self, upload_id: str) -> None:
        stat = self.file.stat()
        if (stat.st_size, stat.st_mtime_ns) != (self.size, self.mtime_ns):
            with contextlib.suppress(*NETWORK_ERRORS):
                self.server.request("DELETE", self.server.path(f"uploads/{upload_id}"))
            self.state.forget()
            raise SubmitError(
                f"{self.file} changed while it was being uploaded (its size or modification time); "
                f"upload {upload_id} was deleted: run the command again to send the file as it is now"
            )

    def _complete(self, upload_id: str) -> dict | None:
        """The queued submission's status; None when the server holds less than the whole file (self.offset set)."""
        path = self.server.path(f"uploads/{upload_id}/complete")
        timeout = 600 + self.size / 2**24  # the server checks the whole upload before it answers
        retrier = Retrier(self.policy, self.log)
        while True:
            try:
                answer = self.server.request("POST", path, timeout=timeout)
            except NETWORK_ERRORS as error:
                retrier.network_failure(self.server, "completing the upload", error)
                continue
            held = answer.offset()
            if answer.status == 202:
                status = answer.json()
                if not isinstance(status.get("id"), str):
                    raise ProtocolError("the server's answer to completing the upload holds no submission id")
                self.state.save(submission_id=status["id"])
                return status
            if answer.status in (404, 410):
                raise _UploadGone(f"the server no longer has upload {upload_id} ({answer.status}: {answer.detail()})")
            if answer.status == 409 and held is not None and held < self.size:
                self.log(f"the server holds {held:,} of {self.size:,} bytes of upload {upload_id}: sending the rest")
                self.offset = held
                return None
            try:
                if answer.status == 409:  # a complete of it at work (an interrupted one of ours)
                    retrier.wait("completing the upload", f"409 {answer.detail()}", answer.retry_after())
                elif answer.status in RETRYABLE_STATUS:
                    retrier.wait("completing the upload", *status_reason(answer))
                else:
                    if answer.status not in (403, 429):  # refused for good: the server dropped the bytes
                        self.state.forget()
                    raise refused(answer)
            except SubmissionRefused as refusal:
                if refusal.status == 429:
                    raise SubmissionRefused(
                        429,
                        refusal.detail,
                        "; the uploaded bytes stay on the server: run the "
                        "same command again later to complete the upload",
                    ) from None
                raise
