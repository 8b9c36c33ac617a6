"""`/v1/submissions`: upload a whole submission, follow it, fetch its results."""

from __future__ import annotations

import json
from typing import Annotated, Literal

from fastapi import APIRouter, Header, HTTPException, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, Response, StreamingResponse

from .. import jobs, results, scenes
from ..models import ResultScenarios, ResultSummary, SubmissionList, SubmissionStatus, status_of
from ..results import result_csv  # noqa: F401  (the in-memory CSV builder, once defined here)
from ..service import Key, ServiceDep
from ..uploads import BodyTooLarge, stream_body_to
from .params import (
    MAX_HEADER_INT,
    OCTET_BODY,
    SUBMISSION_LINKS,
    ChallengeQ,
    ConfigQ,
    MethodQ,
    PartialQ,
    PublishQ,
    SubmissionId,
)

router = APIRouter(prefix="/v1/submissions", tags=["submissions"])


def refuse_forms(request: Request) -> None:
    """A multipart form upload (curl -F, a browser's file form) is refused before its body is read, saying
    how to send the file: as the raw body. (curl --data-binary labels a raw body
    application/x-www-form-urlencoded unless told otherwise: that one is the file itself, and accepted.)"""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind == "multipart/form-data":
        raise HTTPException(
            415,
            "the submission is sent as a multipart form; send the file itself as the raw body "
            "(curl --data-binary @submission.tar.gz -H 'Content-Type: application/octet-stream')",
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
    challenge: ChallengeQ = "sim_agents",
    config: ConfigQ = None,
    method: MethodQ = None,
    publish: PublishQ = False,
    allow_partial: PartialQ = False,
    content_length: Annotated[int | None, Header(ge=0, le=MAX_HEADER_INT)] = None,
):
    """Upload a whole submission (`.tar.gz`, `.tar.bz2`, `.tar.xz`, `.tar` or one `.binproto`, optionally
    compressed) as the raw request body."""
    refuse_forms(request)
    config = svc.config_for(challenge, config)
    method = await run_in_threadpool(svc.check_method, key, challenge, method or key.name)
    async with svc.upload_slot(key, content_length) as hold:  # 429/413 here, before a byte is read
        limit = await run_in_threadpool(svc.upload_limit, key, None, hold, True)
        temp = svc.settings.uploads_dir / f"{jobs.new_id()}.body"
        await run_in_threadpool(svc.admit_body, temp, content_length)  # 507 when the disk has no room for it
        try:
            row = await _receive_and_accept(
                request,
                svc,
                key,
                temp,
                limit,
                content_length,
                hold=hold,
                method=method,
                challenge=challenge,
                config=config,
                allow_partial=allow_partial,
                publish=publish,
            )
        finally:
            svc.forget_body(temp)  # the job row counts its files from here on
    return svc.accepted(row)


async def _receive_and_accept(
    request: Request, svc, key, temp, limit: int, content_length: int | None, *, hold, **params
) -> dict:
    """Stream the body to `temp` (at most `limit` bytes), then check and accept it; `temp` is gone after."""
    try:
        size, disconnected = await stream_body_to(request, temp, limit)
    except BodyTooLarge:
        temp.unlink(missing_ok=True)
        raise svc.too_large(key) from None
    except BaseException:
        temp.unlink(missing_ok=True)
        raise
    if disconnected or (content_length is not None and size != content_length):
        temp.unlink(missing_ok=True)
        raise HTTPException(
            400,
            f"the body ended after {size} bytes (client disconnected or sent "
            "less than Content-Length); use /v1/uploads to resume large uploads",
        )
    try:
        async with svc.check_slots:
            return await run_in_threadpool(svc.accept, key, temp, size, hold=hold, **params)
    finally:
        temp.unlink(missing_ok=True)  # gone already when accepted (renamed)


@router.get("", response_model=SubmissionList, operation_id="listSubmissions")
def list_submissions(svc: ServiceDep, key: Key, limit: Annotated[int, Query(ge=1, le=1000)] = 100):
    """Your submissions, newest first."""
    return SubmissionList(submissions=[status_of(r) for r in jobs.list_submissions(svc.store, key.id, limit)])


@router.get("/{submission_id}", response_model=SubmissionStatus, operation_id="getSubmission")
def get_submission(svc: ServiceDep, key: Key, submission_id: SubmissionId):
    return status_of(svc.own_submission(key, submission_id))


def _stored_result(svc, key, submission_id: str) -> results.StoredResult:
    """The submission's stored result, opened (its files stay readable while it is sent): 404 for another
    key's id, 409 until it is done, 410 when the result is gone from the server's disk or damaged."""
    row = svc.own_submission(key, submission_id)
    if row["state"] != "done":
        detail = f"submission {submission_id} is {row['state']}; results exist once it is done"
        if row["state"] == "failed":
            detail = f"submission {submission_id} failed: {row['error']}"
        raise HTTPException(409, detail)
    try:
        stored = results.open_result(svc.settings.results_dir, submission_id)
    except results.ResultDamaged as exc:
        raise HTTPException(
            410,
            f"the result file of submission {submission_id} is damaged on the server ({exc}); "
            "ask its operator to restore it (or submit again)",
        ) from None
    if stored is None:
        raise HTTPException(
            410,
            f"the result file of submission {submission_id} is missing on the server; "
            "ask its operator to restore it (or submit again)",
        )
    return stored


def _streamed(stored: results.StoredResult, chunks, media_type: str, size: int | None = None) -> StreamingResponse:
    """An answer sent piece by piece from `chunks` (read in the thread pool); the result's files are closed
    when it ends, sent whole or not."""

    def pieces():
        try:
            yield from chunks
        finally:
            stored.close()

    headers = {"Content-Length": str(size)} if size is not None else None
    return StreamingResponse(pieces(), media_type=media_type, headers=headers)


@router.get(
    "/{submission_id}/results",
    operation_id="getResults",
    responses={
        200: {"content": {"application/json": {}, "text/csv": {}}},
        409: {"description": "Not scored (yet)"},
        410: {"description": "The result is gone from the server's disk"},
    },
)
def get_results(
    svc: ServiceDep, key: Key, submission_id: SubmissionId, format: Annotated[Literal["json", "csv"], Query()] = "json"
):
    """The result JSON, exactly as `wosac-eval score` writes it (or per-scenario CSV), streamed: a
    validation-size result (44,097 scenarios) is about 140 MB; `getResultSummary` is the document
    without its rows, `getResultScenarios` pages them."""
    stored = _stored_result(svc, key, submission_id)
    try:
        if format == "json":
            return _streamed(stored, stored.json_chunks(), "application/json", stored.json_size())
        return _streamed(stored, stored.csv(), "text/csv")
    except results.ResultDamaged as exc:  # found before a byte was sent (the CSV's columns)
        stored.close()
        raise HTTPException(
            410, f"the result file of submission {submission_id} is damaged on the server ({exc})"
        ) from exc
    except BaseException:
        stored.close()
        raise


@router.get(
    "/{submission_id}/results/summary",
    operation_id="getResultSummary",
    responses={
        200: {"model": ResultSummary},
        409: {"description": "Not scored (yet)"},
        410: {"description": "The result is gone from the server's disk"},
    },
)
def get_result_summary(svc: ServiceDep, key: Key, submission_id: SubmissionId):
    """The result JSON without its per-scenario rows (`scenarios`): buckets, aggregate, coverage,
    validation, analysis..."""
    stored = _stored_result(svc, key, submission_id)
    try:
        summary = stored.summary()
    except results.ResultDamaged as exc:
        raise HTTPException(
            410, f"the result file of submission {submission_id} is damaged on the server ({exc})"
        ) from exc
    finally:
        stored.close()
    return Response(json.dumps(summary, allow_nan=True), media_type="application/json")


@router.get(
    "/{submission_id}/results/scenarios",
    operation_id="getResultScenarios",
    responses={
        200: {"model": ResultScenarios},
        409: {"description": "Not scored (yet)"},
        410: {"description": "The result is gone from the server's disk"},
    },
)
def get_result_scenarios(
    svc: ServiceDep,
    key: Key,
    submission_id: SubmissionId,
    offset: Annotated[int, Query(ge=0, le=MAX_HEADER_INT)] = 0,
    limit: Annotated[int, Query(ge=1, le=results.MAX_PAGE)] = results.MAX_PAGE,
):
    """A page of the result's per-scenario rows (the `scenarios` of the result JSON), in its order:
    rows offset .. offset+limit-1, and how many there are."""
    stored = _stored_result(svc, key, submission_id)
    try:
        total, rows = stored.page(offset, limit)
    except results.ResultDamaged as exc:
        raise HTTPException(
            410, f"the result file of submission {submission_id} is damaged on the server ({exc})"
        ) from exc
    finally:
        stored.close()
    # The rows' JSON text as stored (NaN included, as in the result JSON), not decoded and encoded again.
    body = f'{{"total": {total}, "offset": {offset}, "scenarios": [{", ".join(rows)}]}}'
    return Response(body, media_type="application/json")


def _done(svc, key, submission_id: str) -> dict:
    row = svc.own_submission(key, submission_id)
    if row["state"] != "done":
        raise HTTPException(409, f"submission {submission_id} is {row['state']}; scenes exist once it is done")
    return row


@router.get("/{submission_id}/scenes", operation_id="listScenes")
def list_scenes(svc: ServiceDep, key: Key, submission_id: SubmissionId):
    """The pictures of the lowest meta-metric scenes (map, log, rollouts, events), worst first, each with
    its row in the result, its worst objects (the objects that cost its buckets most) and, when drawn, the
    picture of its worst object against its log."""
    _done(svc, key, submission_id)
    base = f"/v1/submissions/{submission_id}"
    return {
        "scenes": [
            {
                **entry,
                "url": f"{base}/scenes/{entry['rank']}.png",
                "object_url": (f"{base}/scenes/{entry['rank']}/object.png" if entry["object_picture"] else None),
            }
            for entry in scenes.scene_index(svc.settings, submission_id)
        ]
    }


@router.get(
    "/{submission_id}/scenes/{rank}.png",
    operation_id="getScenePicture",
    responses={200: {"content": {"image/png": {}}}, 404: {"description": "No such picture"}},
)
def get_scene_picture(svc: ServiceDep, key: Key, submission_id: SubmissionId, rank: Annotated[int, Path(ge=0, le=100)]):
    """One picture of `listScenes`, by its rank."""
    _done(svc, key, submission_id)
    return FileResponse(scenes.picture_path(svc.settings, submission_id, rank), media_type="image/png")


@router.get(
    "/{submission_id}/scenes/{rank}/object.png",
    operation_id="getSceneObjectPicture",
    responses={200: {"content": {"image/png": {}}}, 404: {"description": "No such picture"}},
)
def get_scene_object_picture(
    svc: ServiceDep, key: Key, submission_id: SubmissionId, rank: Annotated[int, Path(ge=0, le=100)]
):
    """The worst object of a scene of `listScenes` against its log (its rollouts and features), by rank."""
    _done(svc, key, submission_id)
    return FileResponse(scenes.picture_path(svc.settings, submission_id, rank, of_object=True), media_type="image/png")


@router.get(
    "/{submission_id}/results/scenarios/{row}",
    operation_id="getResultScene",
    responses={
        200: {"content": {"application/json": {}}},
        404: {"description": "No such row"},
        409: {"description": "Not scored (yet)"},
        410: {"description": "The result is gone from the server's disk"},
    },
)
def get_result_scene(
    svc: ServiceDep, key: Key, submission_id: SubmissionId, row: Annotated[int, Path(ge=0, le=MAX_HEADER_INT)]
):
    """One scene of the result by its row (0 .. num_scenarios-1, the order of `getResultScenarios`): its row
    (`scenario`), how many objects were evaluated in it, its worst objects (each one's part of the scene's
    bucket gaps, `wosac_eval.results.worst_objects.scene_worst_objects`) and, for a pictured scene, its
    rank in `listScenes`."""
    row_ = _done(svc, key, submission_id)
    detail = scenes.scene_detail(svc.settings, row_, row)
    return Response(json.dumps(detail, allow_nan=True), media_type="application/json")
