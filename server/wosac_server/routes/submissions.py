"""`/v1/submissions`: upload a whole submission, follow it, fetch its results."""
from __future__ import annotations

import csv
import io
import json
from typing import Annotated, Literal

from fastapi import APIRouter, Header, HTTPException, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, PlainTextResponse

from .. import jobs
from ..models import SubmissionList, SubmissionStatus, status_of
from ..service import Key, ServiceDep
from ..uploads import BodyTooLarge, stream_body_to
from .params import (MAX_HEADER_INT, OCTET_BODY, SUBMISSION_LINKS, ChallengeQ, ConfigQ, MethodQ, PartialQ,
                     PublishQ, SubmissionId)

router = APIRouter(prefix="/v1/submissions", tags=["submissions"])


def refuse_forms(request: Request) -> None:
    """A multipart form upload (curl -F, a browser's file form) is refused before its body is read, saying
    how to send the file: as the raw body. (curl --data-binary labels a raw body
    application/x-www-form-urlencoded unless told otherwise: that one is the file itself, and accepted.)"""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind == "multipart/form-data":
        raise HTTPException(415, "the submission is sent as a multipart form; send the file itself as the raw body "
                            "(curl --data-binary @submission.tar.gz -H 'Content-Type: application/octet-stream')")


@router.post("", status_code=202, response_model=SubmissionStatus, openapi_extra=OCTET_BODY,
             operation_id="createSubmission",
             responses={202: SUBMISSION_LINKS, 413: {"description": "Body too large"},
                        429: {"description": "Quota exceeded"}, 403: {"description": "Method name owned by another key"},
                        415: {"description": "Not a submission (JSON, an image, a zip...)"},
                        422: {"description": "Not a readable submission container, or over an input limit"}})
async def create_submission(request: Request, svc: ServiceDep, key: Key, challenge: ChallengeQ = "sim_agents",
                            config: ConfigQ = None, method: MethodQ = None, publish: PublishQ = False,
                            allow_partial: PartialQ = False,
                            content_length: Annotated[int | None, Header(ge=0, le=MAX_HEADER_INT)] = None):
    """Upload a whole submission (`.tar.gz`, `.tar.bz2`, `.tar.xz`, `.tar` or one `.binproto`, optionally
    compressed) as the raw request body."""
    refuse_forms(request)
    config = svc.config_for(challenge, config)
    method = await run_in_threadpool(svc.check_method, key, challenge, method or key.name)
    async with svc.upload_slot(key, content_length) as hold:  # 429/413 here, before a byte is read
        limit = await run_in_threadpool(svc.upload_limit, key, None, hold)
        temp = svc.settings.uploads_dir / f"{jobs.new_id()}.body"
        try:
            size, disconnected = await stream_body_to(request, temp, limit)
        except BodyTooLarge:
            temp.unlink(missing_ok=True)
            raise svc.too_large(key)
        except BaseException:
            temp.unlink(missing_ok=True)
            raise
        if disconnected or (content_length is not None and size != content_length):
            temp.unlink(missing_ok=True)
            raise HTTPException(400, f"the body ended after {size} bytes (client disconnected or sent "
                                "less than Content-Length); use /v1/uploads to resume large uploads")
        try:
            async with svc.check_slots:
                row = await run_in_threadpool(svc.accept, key, temp, size, method=method, challenge=challenge,
                                              config=config, allow_partial=allow_partial, publish=publish,
                                              hold=hold)
        finally:
            temp.unlink(missing_ok=True)  # gone already when accepted (renamed)
    return svc.accepted(row)


@router.get("", response_model=SubmissionList, operation_id="listSubmissions")
def list_submissions(svc: ServiceDep, key: Key, limit: Annotated[int, Query(ge=1, le=1000)] = 100):
    """Your submissions, newest first."""
    return SubmissionList(submissions=[status_of(r) for r in jobs.list_submissions(svc.store, key.id, limit)])


@router.get("/{submission_id}", response_model=SubmissionStatus, operation_id="getSubmission")
def get_submission(svc: ServiceDep, key: Key, submission_id: SubmissionId):
    return status_of(svc.own_submission(key, submission_id))


@router.get("/{submission_id}/results", operation_id="getResults",
            responses={200: {"content": {"application/json": {}, "text/csv": {}}},
                       409: {"description": "Not scored (yet)"}})
def get_results(svc: ServiceDep, key: Key, submission_id: SubmissionId,
                format: Annotated[Literal["json", "csv"], Query()] = "json"):
    """The result JSON, exactly as `wosac-eval score` writes it (or per-scenario CSV)."""
    row = svc.own_submission(key, submission_id)
    if row["state"] != "done":
        detail = f"submission {submission_id} is {row['state']}; results exist once it is done"
        if row["state"] == "failed":
            detail = f"submission {submission_id} failed: {row['error']}"
        raise HTTPException(409, detail)
    path = svc.settings.results_dir / f"{submission_id}.json"
    if not path.is_file():
        raise HTTPException(410, f"the result file of submission {submission_id} is missing on the server; "
                            "ask its operator to restore it (or submit again)")
    if format == "json":
        return FileResponse(path, media_type="application/json")
    with open(path) as f:
        return PlainTextResponse(result_csv(json.load(f)), media_type="text/csv")


def _done(svc, key, submission_id: str) -> dict:
    row = svc.own_submission(key, submission_id)
    if row["state"] != "done":
        raise HTTPException(409, f"submission {submission_id} is {row['state']}; pictures exist once it is done")
    return row


def _scene_index(svc, submission_id: str) -> list[dict]:
    path = svc.settings.scenes_dir(submission_id) / "scenes.json"
    if not path.is_file():
        return []
    with open(path) as f:
        return json.load(f)["scenes"]


@router.get("/{submission_id}/scenes", operation_id="listScenes")
def list_scenes(svc: ServiceDep, key: Key, submission_id: SubmissionId):
    """The pictures of the lowest meta-metric scenes (map, log, rollouts, events), worst first."""
    _done(svc, key, submission_id)
    return {"scenes": [{**entry, "url": f"/v1/submissions/{submission_id}/scenes/{entry['rank']}.png"}
                       for entry in _scene_index(svc, submission_id)]}


@router.get("/{submission_id}/scenes/{rank}.png", operation_id="getScenePicture",
            responses={200: {"content": {"image/png": {}}}, 404: {"description": "No such picture"}})
def get_scene_picture(svc: ServiceDep, key: Key, submission_id: SubmissionId,
                      rank: Annotated[int, Path(ge=0, le=100)]):
    """One picture of `listScenes`, by its rank."""
    _done(svc, key, submission_id)
    if not any(entry["rank"] == rank for entry in _scene_index(svc, submission_id)):
        raise HTTPException(404, f"submission {submission_id} has no scene picture {rank}")
    picture = svc.settings.scenes_dir(submission_id) / f"{rank}.png"
    if not picture.is_file():
        raise HTTPException(410, f"picture {rank} of submission {submission_id} is missing on the server")
    return FileResponse(picture, media_type="image/png")


def result_csv(result: dict) -> str:
    """Per-scenario rows of a result JSON: `scenario_id`, then every metric field."""
    scenarios = result.get("scenarios") or []
    fields: list[str] = []
    for s in scenarios:
        for k in s:
            if k not in fields and not isinstance(s[k], (dict, list)):
                fields.append(k)
    if "scenario_id" in fields:
        fields.remove("scenario_id")
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["scenario_id", *fields])
    for s in scenarios:
        writer.writerow([s.get("scenario_id"), *(repr(s[k]) if isinstance(s.get(k), float) else s.get(k, "")
                                                 for k in fields)])
    return out.getvalue()
