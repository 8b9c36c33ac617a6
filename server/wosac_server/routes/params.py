"""Query, path and header parameters shared by the routes, and the OpenAPI links between operations."""

from __future__ import annotations

from typing import Annotated

from fastapi import Path as PathParam
from fastapi import Query

from ..auth import METHOD_PATTERN
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
