"""Query, path and header parameters shared by the routes, the request body as the service reads it,
and the OpenAPI links between operations."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import Depends, Query, Request
from fastapi import Path as PathParam
from starlette.requests import ClientDisconnect

from ..auth import METHOD_PATTERN
from ..jobs import SubmissionParams
from ..models import Challenge

MAX_HEADER_INT = 2**62  # fits a BIGINT on every engine

ChallengeQ = Annotated[
    Challenge,
    Query(
        description="The challenge: sim_agents (80 future steps) or scenario_gen "
        "(91 steps of every object, with box sizes and types)."
    ),
]
ConfigQ = Annotated[
    str | None, Query(description="Metric config (default: the challenge's current one, 2025 or scenario_gen_2025).")
]
MethodQ = Annotated[
    str | None, Query(pattern=METHOD_PATTERN, description="Method name on the leaderboard (default: key name).")
]
PublishQ = Annotated[bool, Query(description="Show the result on the public leaderboard.")]
PartialQ = Annotated[bool, Query(description="Score only the scenarios the submission covers.")]


def submission_params(
    challenge: ChallengeQ = "sim_agents",
    config: ConfigQ = None,
    method: MethodQ = None,
    publish: PublishQ = False,
    allow_partial: PartialQ = False,
) -> SubmissionParams:
    """The five query parameters of a submission, declared once for every route that takes them."""
    return SubmissionParams(challenge, config, method, publish, allow_partial)


Params = Annotated[SubmissionParams, Depends(submission_params)]
SubmissionId = Annotated[str, PathParam(description="Submission id (32 hex digits).")]
UploadId = Annotated[str, PathParam(description="Upload id (32 hex digits).")]

# OpenAPI links: which operation can follow which, with the id taken from the answer.
SUBMISSION_LINKS = {
    "links": {
        "status": {"operationId": "getSubmission", "parameters": {"submission_id": "$response.body#/id"}},
        "results": {"operationId": "getResults", "parameters": {"submission_id": "$response.body#/id"}},
        "resultSummary": {"operationId": "getResultSummary", "parameters": {"submission_id": "$response.body#/id"}},
        "resultScenarios": {"operationId": "getResultScenarios", "parameters": {"submission_id": "$response.body#/id"}},
    }
}
UPLOAD_LINKS = {
    "links": {
        op: {"operationId": op, "parameters": {"upload_id": "$response.body#/upload_id"}}
        for op in ("getUpload", "headUpload", "patchUpload", "completeUpload", "deleteUpload")
    }
}
OCTET_BODY = {
    "requestBody": {
        "required": True,
        "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
    }
}


class ClientBody:
    """The request's body for the service (`uploads.Body`): its chunks as they arrive; `cut` once the client
    went away before its end."""

    def __init__(self, request: Request):
        self.request = request
        self.cut = False

    async def __aiter__(self) -> AsyncIterator[bytes]:
        try:
            async for chunk in self.request.stream():
                yield chunk
        except ClientDisconnect:
            self.cut = True
