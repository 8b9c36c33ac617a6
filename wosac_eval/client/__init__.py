"""A client of the wosac-server scoring service (server/), on the standard library's HTTP alone; its
uploads speak tus 1.0.0 (`tus.py`), so any tus server of the service's API takes them.

  submit(path, SubmitOptions(...) or its fields by name: server=URL, key=KEY, method=NAME,
         challenge="sim_agents", config=None, publish=False, allow_partial=False, output=None, ...;
         wait=False, new=False) -> the submission's status
      A resumable, chunked upload that survives interruptions (run it again: it goes on from the
      server's offset), retried with backoff; with wait=True, followed to its result.
  follow(submission_id, FollowOptions(...) or its fields: server=URL, key=KEY, output=None, ...)
      -> the final status with its result
  SubmitError and its kinds: SubmissionRefused (4xx: .status, .detail), SubmissionFailed (the job
  failed: .status), ServerUnavailable (past the retry budget; AnswerTooSlow: an answer past its
  deadline), ProtocolError (an answer that is not the service's, naming what it lacks); ArgumentError
  (a ValueError) for bad arguments, raised before anything is sent.
  RetryPolicy(attempts, base_s, cap_s, max_wait_s, answer_deadline_s): how long each request is retried,
  and how long a status or result answer may take to come whole.

`wosac-eval submit` is this function on the command line.
"""

from __future__ import annotations

from wosac_eval.client.following import FollowOptions, follow
from wosac_eval.client.transport import (
    KEY_ENV,
    AnswerTooSlow,
    ArgumentError,
    ProtocolError,
    RetryPolicy,
    ServerUnavailable,
    SubmissionFailed,
    SubmissionRefused,
    SubmitError,
)
from wosac_eval.client.uploads import DEFAULT_CHUNK_BYTES, SubmitOptions, submit

__all__ = [
    "DEFAULT_CHUNK_BYTES",
    "FollowOptions",
    "KEY_ENV",
    "AnswerTooSlow",
    "ArgumentError",
    "ProtocolError",
    "RetryPolicy",
    "ServerUnavailable",
    "SubmissionFailed",
    "SubmissionRefused",
    "SubmitError",
    "SubmitOptions",
    "follow",
    "submit",
]
