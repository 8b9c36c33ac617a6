"""`/v1/submissions`: upload a whole submission, follow it, fetch its results.

HTTP only: parameters in, answers out. The rules are the service layer's (`intake`, `reading`); its
refusals become status codes in `answers`.
"""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Header, Path, Query, Request
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse

from ..errors import NotASubmission
from ..intake import receive_submission
from ..models import ResultScenarios, ResultSummary, SubmissionList, SubmissionStatus, status_of
from ..reading import MAX_PAGE, ReadingDep, page_text, readable_csv, sent_then_closed, summary_text
from ..service import Key, ServiceDep
from .params import MAX_HEADER_INT, OCTET_BODY, SUBMISSION_LINKS, ClientBody, Params, SubmissionId

router = APIRouter(prefix="/v1/submissions", tags=["submissions"])
NOT_READY = {"description": "Not scored (yet)"}
GONE = {"description": "The result is gone from the server's disk"}
PICTURE: dict[int | str, dict[str, Any]] = {
    200: {"content": {"image/png": {}}},
    404: {"description": "No such picture"},
}


def accepted(row: dict) -> JSONResponse:
    """`202` with the new submission's status, and where to follow it."""
    return JSONResponse(
        status_of(row).model_dump(), status_code=202, headers={"Location": f"/v1/submissions/{row['id']}"}
    )


def refuse_forms(request: Request) -> None:
    """A multipart form upload (curl -F, a browser's file form) is refused before its body is read, saying
    how to send the file: as the raw body. (curl --data-binary labels a raw body
    application/x-www-form-urlencoded unless told otherwise: that one is the file itself, and accepted.)"""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind == "multipart/form-data":
        raise NotASubmission(
            "the submission is sent as a multipart form; send the file itself as the raw body "
            "(curl --data-binary @submission.tar.gz -H 'Content-Type: application/octet-stream')"
        )


@router.post(
    "",
    status_code=202,
    response_model=SubmissionStatus,
    openapi_extra=OCTET_BODY,
    operation_id="createSubmission",
    responses={
        202: SUBMISSION_LINKS,
        413: {"description": "Body too large"},
        429: {"description": "Quota exceeded"},
        403: {"description": "Method name owned by another key"},
        415: {"description": "Not a submission (JSON, an image, a zip...)"},
        422: {"description": "Not a readable submission container, or over an input limit"},
        507: {"description": "The server's disk is full or past its floor; retry after Retry-After seconds"},
    },
)
async def create_submission(
    request: Request,
    svc: ServiceDep,
    key: Key,
    params: Params,
    content_length: Annotated[int | None, Header(ge=0, le=MAX_HEADER_INT)] = None,
):
    """Upload a whole submission (`.tar.gz`, `.tar.bz2`, `.tar.xz`, `.tar` or one `.binproto`, optionally
    compressed) as the raw request body."""
    refuse_forms(request)
    return accepted(await receive_submission(svc, key, ClientBody(request), content_length, params))


@router.get("", response_model=SubmissionList, operation_id="listSubmissions")
def list_submissions(read: ReadingDep, key: Key, limit: Annotated[int, Query(ge=1, le=1000)] = 100):
    """Your submissions, newest first."""
    return SubmissionList(submissions=[status_of(r) for r in read.submissions(key, limit)])


@router.get("/{submission_id}", response_model=SubmissionStatus, operation_id="getSubmission")
def get_submission(svc: ServiceDep, key: Key, submission_id: SubmissionId):
    return status_of(svc.own_submission(key, submission_id))


@router.get(
    "/{submission_id}/results",
    operation_id="getResults",
    responses={200: {"content": {"application/json": {}, "text/csv": {}}}, 409: NOT_READY, 410: GONE},
)
def get_results(
    read: ReadingDep, key: Key, submission_id: SubmissionId, format: Annotated[Literal["json", "csv"], Query()] = "json"
):
    """The result JSON, exactly as `wosac-eval score` writes it (or per-scenario CSV), streamed from the
    stored files: a validation-size result (44,097 scenarios) is about 140 MB; `getResultSummary` is the
    document without its rows, `getResultScenarios` pages them."""
    stored = read.stored_result(key, submission_id)
    if format == "json":
        size = stored.json_size()
        headers = {"Content-Length": str(size)} if size is not None else None
        return StreamingResponse(
            sent_then_closed(stored, stored.json_chunks()), media_type="application/json", headers=headers
        )
    return StreamingResponse(sent_then_closed(stored, readable_csv(stored, submission_id)), media_type="text/csv")


@router.get(
    "/{submission_id}/results/summary",
    operation_id="getResultSummary",
    responses={200: {"model": ResultSummary}, 409: NOT_READY, 410: GONE},
)
def get_result_summary(read: ReadingDep, key: Key, submission_id: SubmissionId):
    """The result JSON without its per-scenario rows (`scenarios`): buckets, aggregate, coverage,
    validation, analysis..."""
    return Response(summary_text(read.stored_result(key, submission_id), submission_id), media_type="application/json")


@router.get(
    "/{submission_id}/results/scenarios",
    operation_id="getResultScenarios",
    responses={200: {"model": ResultScenarios}, 409: NOT_READY, 410: GONE},
)
def get_result_scenarios(
    read: ReadingDep,
    key: Key,
    submission_id: SubmissionId,
    offset: Annotated[int, Query(ge=0, le=MAX_HEADER_INT)] = 0,
    limit: Annotated[int, Query(ge=1, le=MAX_PAGE)] = MAX_PAGE,
):
    """A page of the result's per-scenario rows (the `scenarios` of the result JSON), in its order:
    rows offset .. offset+limit-1, and how many there are."""
    text = page_text(read.stored_result(key, submission_id), submission_id, offset, limit)
    return Response(text, media_type="application/json")


@router.get("/{submission_id}/scenes", operation_id="listScenes")
def list_scenes(read: ReadingDep, key: Key, submission_id: SubmissionId):
    """The pictures of the lowest meta-metric scenes (map, log, rollouts, events), worst first, each with
    its row in the result, its worst objects (the objects that cost its buckets most) and, when drawn, the
    picture of its worst object against its log."""
    base = f"/v1/submissions/{submission_id}"
    return {
        "scenes": [
            {
                **entry,
                "url": f"{base}/scenes/{entry['rank']}.png",
                "object_url": (f"{base}/scenes/{entry['rank']}/object.png" if entry["object_picture"] else None),
            }
            for entry in read.scenes(key, submission_id)
        ]
    }


@router.get("/{submission_id}/scenes/{rank}.png", operation_id="getScenePicture", responses=PICTURE)
def get_scene_picture(
    read: ReadingDep, key: Key, submission_id: SubmissionId, rank: Annotated[int, Path(ge=0, le=100)]
):
    """One picture of `listScenes`, by its rank."""
    return FileResponse(read.picture(key, submission_id, rank, of_object=False), media_type="image/png")


@router.get("/{submission_id}/scenes/{rank}/object.png", operation_id="getSceneObjectPicture", responses=PICTURE)
def get_scene_object_picture(
    read: ReadingDep, key: Key, submission_id: SubmissionId, rank: Annotated[int, Path(ge=0, le=100)]
):
    """The worst object of a scene of `listScenes` against its log (its rollouts and features), by rank."""
    return FileResponse(read.picture(key, submission_id, rank, of_object=True), media_type="image/png")


@router.get(
    "/{submission_id}/results/scenarios/{row}",
    operation_id="getResultScene",
    responses={
        200: {"content": {"application/json": {}}},
        404: {"description": "No such row"},
        409: NOT_READY,
        410: GONE,
    },
)
def get_result_scene(
    read: ReadingDep, key: Key, submission_id: SubmissionId, row: Annotated[int, Path(ge=0, le=MAX_HEADER_INT)]
):
    """One scene of the result by its row (0 .. num_scenarios-1, the order of `getResultScenarios`): its row
    (`scenario`), how many objects were evaluated in it, its worst objects (each one's part of the scene's
    bucket gaps, `wosac_eval.results.worst_objects.scene_worst_objects`) and, for a pictured scene, its
    rank in `listScenes`."""
    return Response(json.dumps(read.scene(key, submission_id, row), allow_nan=True), media_type="application/json")
