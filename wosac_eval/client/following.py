"""Following a submission on a wosac-server: its state polled until it is done or failed, each change
said, the scoring's progress reported, and the result fetched (its figures; the whole document streamed to
a file on request). `submit(..., wait=True)` follows the submission it uploaded; `follow` one already there.
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

from wosac_eval.client.transport import (
    ArgumentError,
    Response,
    Retrier,
    RetryPolicy,
    Server,
    SubmissionFailed,
    SubmitError,
    api_key,
    call,
    options_with,
    refused,
    required,
)

FINAL_STATES = ("done", "failed")
NUMBER = (int, float)
# What this client reads of the server's answers (`transport.required` names what one lacks).
STATUS_FIELDS: dict[str, type | tuple[type, ...]] = {"id": str, "state": str, "method": str, "progress": dict}
RESULT_FIELDS: dict[str, type | tuple[type, ...]] = {
    "buckets": dict,
    "num_scenarios": int,
    "challenge": str,
    "config": str,
}
BUCKET_FIELDS: dict[str, type | tuple[type, ...]] = dict.fromkeys(
    ("realism_meta_metric", "kinematic_metrics", "interactive_metrics", "map_based_metrics", "min_ade"), NUMBER
)
# progress(stage, done, total): stage "upload" counts bytes the server holds (or that are on their way),
# "scoring" the job's scenarios (total None until validation has read the submission).
Progress = Callable[[str, int, "int | None"], None]

_logger = logging.getLogger("wosac_eval.client")


@dataclasses.dataclass(frozen=True)
class FollowOptions:
    """What `follow` is told besides the submission's id (the fields as `submit`'s of the same names)."""

    server: str
    key: str | None = None
    output: str | os.PathLike | None = None
    progress: Progress | None = None
    log: Callable[[str], None] | None = None
    retry: RetryPolicy = RetryPolicy()
    timeout: float = 60.0
    poll_s: tuple[float, float] = (0.5, 5.0)


def follow(submission_id: str, options: FollowOptions | None = None, **fields: Any) -> dict:
    """Follow a submission already on the server until it is done or failed; as `submit(..., wait=True)`.

    The options are a `FollowOptions`, or its fields by name (`follow(id, server=URL, key=KEY)`), or both.
    """
    o = options_with(FollowOptions, options, fields)
    try:
        server = Server(o.server, api_key(o.key), o.timeout, o.retry.answer_deadline_s)
    except ValueError as error:
        raise ArgumentError(str(error)) from None
    follower = Follower(server, o.progress or no_progress, o.log or _logger.info, o.retry, o.poll_s)
    return follower.follow(submission_id, None, o.output)


def no_progress(stage: str, done: int, total: int | None) -> None:
    pass


class Follower:
    """Polls a submission's status until it is final, saying each state change; fetches the result."""

    def __init__(
        self,
        server: Server,
        progress: Progress,
        log: Callable[[str], None],
        retry: RetryPolicy,
        poll_s: tuple[float, float],
    ) -> None:
        self.server, self.progress, self.log, self.policy = server, progress, log, retry
        self.poll_min, self.poll_max = poll_s

    def status(self, submission_id: str) -> dict | None:
        """The submission's status; None when the server does not know it (404)."""
        answer = call(self, "asking for the submission's status", "GET", f"submissions/{submission_id}")
        if answer.status == 404:
            return None
        if answer.status != 200:
            raise refused(answer)
        status = required(answer.json(), STATUS_FIELDS, f"asking for submission {submission_id}'s status")
        required(status["progress"], {"scenarios_done": int}, f"asking for submission {submission_id}'s progress")
        return status

    def follow(self, submission_id: str, status: dict | None, output: str | os.PathLike | None) -> dict:
        """Poll until the job is done or failed (`status`: its status as the caller last saw and said it)."""
        seen, interval, said = None, self.poll_min, status is not None
        try:
            while True:
                if status is None:
                    status = self.status(submission_id)
                    if status is None:
                        raise SubmitError(f"the server has no submission {submission_id} for this key")
                state, done = status["state"], status["progress"]
                now = (state, status.get("attempts"), done.get("scenarios_done"), done.get("scenarios_total"))
                if said:
                    said = False
                elif seen is None or state != seen[0] or now[1] != seen[1]:
                    again = f" (attempt {now[1]})" if (now[1] or 0) > 1 and state not in FINAL_STATES else ""
                    self.log(f"submission {submission_id}: {state}{again}")
                if state == "scoring" or (state == "done" and done.get("scenarios_total")):
                    self.progress("scoring", done.get("scenarios_done") or 0, done.get("scenarios_total"))
                if state in FINAL_STATES:
                    break
                interval = self.poll_min if now != seen else min(self.poll_max, interval * 1.5)
                seen = now
                time.sleep(interval)
                status = None
        except KeyboardInterrupt:
            self.log(
                f"stopped following submission {submission_id}; it goes on at the server: run the same "
                "command again (with --wait) to follow it"
            )
            raise
        if state == "failed":
            raise SubmissionFailed(status)
        return self._with_result(status, output)

    def _with_result(self, status: dict, output: Any) -> dict:
        """The status with its result's figures ("result"); the whole result document written to `output`."""
        route = f"submissions/{status['id']}/results"
        answer = call(self, "fetching the result's summary", "GET", route + "/summary")
        if answer.status == 404 and answer.detail() == "Not Found":  # a server without that route (FastAPI's
            answer = call(self, "fetching the result", "GET", route)  # 404): the whole document, rows too
        if answer.status != 200:
            raise refused(answer)
        result = required(answer.json(), RESULT_FIELDS, f"fetching submission {status['id']}'s result")
        required(result["buckets"], BUCKET_FIELDS, f"fetching submission {status['id']}'s result (its buckets)")
        if output is not None:
            self._download(route, Path(output))
        status = dict(status)
        status["result"] = {
            name: result.get(name) for name in ("challenge", "config", "num_scenarios", "coverage", "buckets")
        }
        return status

    def _download(self, route: str, path: Path) -> None:
        """The result document into `path`, streamed (a validation-size result is ~140 MB), atomically."""
        temp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            with open(temp, "wb") as f:

                def fetch() -> Response:
                    f.seek(0)
                    f.truncate()
                    return self.server.request("GET", self.server.path(route), sink=f, deadline=self.server.deadline_s)

                answer = Retrier(self.policy, self.log).call(self.server, "downloading the result", fetch)
                if answer.status != 200:
                    raise refused(answer)
                f.flush()
                os.fsync(f.fileno())
            os.replace(temp, path)
        finally:
            with contextlib.suppress(FileNotFoundError):
                temp.unlink()
