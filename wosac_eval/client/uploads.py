"""`submit`: send a submission to a wosac-server through its resumable uploads (tus 1.0.0), and follow it to
its result.

The file is sent in chunks (`client.tus.Sender`), read a block at a time, never whole. The upload's id
is kept in a small state file (see `state.py`), so running the same call again after any interruption
(this process killed, the network, the server) asks the server for its offset and goes on from there;
once the upload is a submission, the file keeps the submission's id, and running it again follows that
submission instead of uploading the file again.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from wosac_eval.client.following import Follower, Progress, no_progress
from wosac_eval.client.state import UploadState, default_state_dir, key_digest, prune
from wosac_eval.client.transport import (
    NETWORK_ERRORS,
    ArgumentError,
    ProtocolError,
    RetryPolicy,
    Server,
    ServerUnavailable,
    SubmissionRefused,
    SubmitError,
    api_key,
    options_with,
)
from wosac_eval.client.tus import TUS_VERSION, FileChanged, Sender, UploadGone

DEFAULT_CHUNK_BYTES = 64 * 2**20
CHALLENGES = ("sim_agents", "scenario_gen")

_logger = logging.getLogger("wosac_eval.client")


@dataclasses.dataclass(frozen=True)
class SubmitOptions:
    """Everything `submit` is told besides the file (see `submit` for each)."""

    server: str
    method: str
    key: str | None = None
    challenge: str = "sim_agents"
    config: str | None = None
    publish: bool = False
    allow_partial: bool = False
    output: str | os.PathLike | None = None
    chunk_bytes: int = DEFAULT_CHUNK_BYTES
    limit_rate: int | None = None
    progress: Progress | None = None
    log: Callable[[str], None] | None = None
    state_dir: str | os.PathLike | None = None
    retry: RetryPolicy = RetryPolicy()
    timeout: float = 60.0
    poll_s: tuple[float, float] = (0.5, 5.0)


def submit(
    submission: str | os.PathLike,
    options: SubmitOptions | None = None,
    *,
    wait: bool = False,
    new: bool = False,
    **fields: Any,
) -> dict:
    """Upload `submission` to the wosac-server at `server`, resumably; with `wait`, follow it to its result.

    The options are a `SubmitOptions`, or its fields by name (`submit(path, server=URL, key=KEY,
    method=NAME)`), or both (the fields named replace the object's).

    Args:
      submission: the file (.tar.gz, .tar.bz2, .tar.xz, .tar, or one .binproto, optionally compressed).
      options, fields (`SubmitOptions`):
        server: the service's base URL, e.g. "https://wosac.example.org".
        key: the API key (default: the WOSAC_API_KEY environment variable). Never written to disk.
        method: the leaderboard name. challenge, config, publish, allow_partial: as the server's
          upload parameters (config None: the challenge's current one).
        output: with `wait`, write the result document (the same JSON as `wosac-eval score`) there.
        chunk_bytes: bytes per PATCH request. limit_rate: at most this many bytes per second.
        progress: progress(stage, done, total), stage "upload" (bytes) or "scoring" (scenarios).
        log: called with one line per event (resumed, retrying, state changes); default: the
          "wosac_eval.client" logger at INFO.
        state_dir: where uploads are remembered (default $XDG_CACHE_HOME/wosac-eval/uploads, else
          ~/.cache/wosac-eval/uploads).
        retry: how long each request is retried (network errors, 5xx, 507, 429, 408).
        timeout: seconds a connection may stay silent. poll_s: the first and longest wait between
          two status requests while following the job.
      wait: follow the job until it is done or failed, and fetch its result.
      new: forget an earlier upload of this file (an unfinished one is deleted on the server) and
        upload it again.

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
      ValueError (ArgumentError): a bad argument (no key, a missing or empty file, a bad URL, an
        option `SubmitOptions` does not have), before anything is sent.
    """
    return _Run(submission, options_with(SubmitOptions, options, fields)).run(wait=wait, new=new)


class _Run:
    """One call of `submit`: the arguments checked, the state found, the upload resumed or started."""

    def __init__(self, submission: str | os.PathLike, options: SubmitOptions) -> None:
        _check(options)
        self.file = _submission_file(submission)
        stat = self.file.stat()
        self.size, self.mtime_ns = stat.st_size, stat.st_mtime_ns
        self.key = api_key(options.key)
        try:
            self.server = Server(options.server, self.key, options.timeout, options.retry.answer_deadline_s)
        except ValueError as error:
            raise ArgumentError(str(error)) from None
        self.params = {
            "method": str(options.method),
            "challenge": options.challenge,
            "config": options.config,
            "publish": bool(options.publish),
            "allow_partial": bool(options.allow_partial),
        }
        self.output = options.output
        self.progress = options.progress or no_progress
        self.log = options.log or _logger.info
        self.policy = options.retry
        self.follower = Follower(self.server, self.progress, self.log, options.retry, options.poll_s)
        self.sender = Sender(
            self.server,
            self.file,
            self.size,
            options.retry,
            self.log,
            self.progress,
            int(options.chunk_bytes),
            self.mtime_ns,
            int(options.limit_rate) if options.limit_rate else None,
        )
        folder = _state_folder(options.state_dir)
        identity = {"server": self.server.url, "key": key_digest(self.key), "file": str(self.file), "size": self.size}
        self.state = UploadState(folder, {**identity, "mtime_ns": self.mtime_ns, **self.params})

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
                status = self._earlier_submission(quiet=True) or self._upload_kept()
        if not wait:
            return status
        try:
            return self.follower.follow(status["id"], status, self.output)
        except ServerUnavailable as error:
            raise ServerUnavailable(
                f"{error}; submission {status['id']} goes on at the server: run the same command again to follow it"
            ) from None

    def _upload_kept(self) -> dict:
        """The upload, with what to do next said when it stops while the server keeps its bytes."""
        try:
            return self._upload()
        except ServerUnavailable as error:
            if self.state.data.get("upload_id"):
                raise ServerUnavailable(
                    f"{error}; the server keeps upload {self.state.data['upload_id']}: "
                    "run the same command again to resume it"
                ) from None
            raise
        except FileChanged:
            self.state.forget()
            raise
        except SubmissionRefused as refusal:
            if refusal.status == 429 and self.sender.offset == self.size:
                raise SubmissionRefused(
                    429,
                    refusal.detail,
                    "; the uploaded bytes stay on the server: run the same command again later to complete the upload",
                ) from None
            if refusal.status not in (403, 429) and self.sender.offset == self.size:
                self.state.forget()  # refused for good at its last byte: the server dropped the upload
            raise

    def _forget_earlier(self) -> None:
        upload_id = self.state.data.get("upload_id")
        if upload_id and not self.state.data.get("submission_id"):
            with contextlib.suppress(*NETWORK_ERRORS):
                answer = self.server.request(
                    "DELETE", self.server.path(f"uploads/{upload_id}"), {"Tus-Resumable": TUS_VERSION}
                )
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
            except UploadGone as gone:
                self.state.forget()
                if restart == 2:
                    raise SubmitError(f"{gone}, a third time; giving up") from None
                self.log(f"{gone}; starting a new upload")
        raise AssertionError("unreachable")

    def _upload_once(self) -> dict:
        upload_id = self.state.data.get("upload_id")
        submission_id = None
        if upload_id:
            submission_id = self.sender.head(upload_id)
            self.log(
                f"resuming upload {upload_id} at byte {self.sender.offset:,} of {self.size:,} "
                f"({self.sender.offset / self.size:.0%}), the server's offset"
            )
        else:
            upload_id = self._create()
        resumed_at = self.sender.offset
        self.progress("upload", self.sender.offset, self.size)
        try:
            if submission_id is None:
                submission_id = self.sender.send(upload_id)
        except KeyboardInterrupt:
            self.log(
                f"upload {upload_id} interrupted at byte {self.sender.offset:,} of {self.size:,}; the server keeps "
                "it (for 7 days by default): run the same command again to resume it"
            )
            raise
        self.state.save(submission_id=submission_id)
        status = self.follower.status(submission_id)
        if status is None:
            raise ProtocolError(f"the server named submission {submission_id} for upload {upload_id}, then denied it")
        resumed = f", resumed at byte {resumed_at:,}" if resumed_at else ""
        self.log(
            f"uploaded {self.file.name}: submission {status['id']}, {status['state']} "
            f"(sent {self.sender.sent:,} bytes in {self.sender.patches} PATCH request(s) in this run{resumed})"
        )
        return status

    def _create(self) -> str:
        metadata = {k: _metadata_value(v) for k, v in self.params.items() if v is not None}
        metadata["partial"] = metadata.pop("allow_partial")
        upload_id = self.sender.create({**metadata, "filename": self.file.name})
        self.sender.offset = 0
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
        self.log(f"upload {upload_id} created: {self.size:,} bytes to send in chunks of {self.sender.chunk:,}")
        return upload_id


def _metadata_value(value: object) -> str:
    return ("true" if value else "false") if isinstance(value, bool) else str(value)


def _check(options: SubmitOptions) -> None:
    if options.challenge not in CHALLENGES:
        raise ArgumentError(f"challenge {options.challenge!r}: choose {' or '.join(CHALLENGES)}")
    if not options.method or not str(options.method).strip():
        raise ArgumentError("give the method's leaderboard name (method=...)")
    if int(options.chunk_bytes) < 1:
        raise ArgumentError(f"chunk_bytes must be >= 1, not {options.chunk_bytes}")
    if options.limit_rate is not None and int(options.limit_rate) < 1:
        raise ArgumentError(f"limit_rate must be >= 1 byte per second, not {options.limit_rate}")


def _submission_file(submission: str | os.PathLike) -> Path:
    file = Path(os.path.abspath(submission))
    if not file.exists():
        raise ArgumentError(f"{submission}: no such file")
    if not file.is_file():
        raise ArgumentError(
            f"{submission}: not a file; send the submission as one file (a folder of shards: "
            f"pack it first, e.g. tar czf {file.name}.tar.gz -C {file} .)"
        )
    if file.stat().st_size == 0:
        raise ArgumentError(f"{submission}: the file is empty")
    return file


def _state_folder(state_dir: str | os.PathLike | None) -> Path:
    folder = Path(state_dir) if state_dir is not None else default_state_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    except OSError as error:
        raise ArgumentError(f"state dir {folder}: cannot create it ({error.strerror or error})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ArgumentError(f"state dir {folder}: not writable")
    prune(folder)
    return folder
