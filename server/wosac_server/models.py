"""The API's response models (they make the OpenAPI schema) and how a job row becomes one."""

from __future__ import annotations

import json
from datetime import datetime, timezone
from typing import Any, Literal

from pydantic import BaseModel, Field

Challenge = Literal["sim_agents", "scenario_gen"]


class Progress(BaseModel):
    scenarios_done: int
    scenarios_total: int | None = Field(None, description="Known once validation has read the submission.")


class SubmissionStatus(BaseModel):
    id: str
    state: Literal["queued", "validating", "scoring", "done", "failed"]
    method: str
    challenge: Challenge
    config: str
    published: bool
    allow_partial: bool
    upload_bytes: int
    progress: Progress
    attempts: int = Field(description="Scoring attempts started (a worker that died counts one).")
    created_at: str
    updated_at: str
    started_at: str | None = None
    finished_at: str | None = None
    error: str | None = Field(None, description="Why the submission failed.")
    validation_report: dict[str, Any] | None = Field(
        None, description="The validator's report when the submission was judged invalid."
    )
    realism_meta_metric: float | None = None
    coverage: float | None = Field(
        None, description="Share of the scenario set the result covers (1.0 unless scored with allow_partial)."
    )
    partial: bool = Field(
        False, description="A partial result: scored with allow_partial on part of the scenario set (coverage below 1)."
    )
    results_url: str | None = None
    peak_rss_bytes: int | None = Field(None, description="Peak resident memory of the last scoring attempt's process.")
    cpu_s: float | None = Field(None, description="CPU seconds the last scoring attempt's process used.")


class SubmissionList(BaseModel):
    submissions: list[SubmissionStatus]


class LeaderboardEntry(BaseModel):
    rank: int
    method: str
    submission_id: str
    realism_meta_metric: float
    buckets: dict[str, Any]
    coverage: float | None = Field(None, description="Share of the scenario set scored (below 1: a partial result).")
    partial: bool = Field(False, description="A partial result (coverage below 1): ranked, and marked so.")
    finished_at: str


class Leaderboard(BaseModel):
    challenge: Challenge
    config: str
    entries: list[LeaderboardEntry]


class ResultSummary(BaseModel):
    """A result document without its per-scenario rows (`scenarios`); its other keys as stored."""

    model_config = {"extra": "allow"}

    challenge: Challenge
    config: str
    num_scenarios: int = Field(description="Rows of the result (scenarios scored); page them with getResultScenarios.")
    aggregate: dict[str, Any] = Field(description="Every metric field, mean over the scored scenarios.")
    buckets: dict[str, Any] = Field(description="The bucketed metrics and realism_meta_metric.")
    skipped: list[dict[str, Any]] = Field(description="Scenarios not scored, with the reason.")
    validation: dict[str, Any]
    coverage: dict[str, Any]
    analysis: dict[str, Any] | None = None


class ResultScenarios(BaseModel):
    """One page of a result's per-scenario rows, in the result's order."""

    total: int = Field(description="Rows in the whole result.")
    offset: int = Field(description="Index of the first row of this page.")
    scenarios: list[dict[str, Any]] = Field(
        description="Rows offset .. offset+limit-1 (fewer at the end, none past it)."
    )


class UploadStatus(BaseModel):
    upload_id: str
    offset: int = Field(description="Bytes received and stored so far; the next PATCH starts here.")
    length: int | None = Field(None, description="Total size declared with Upload-Length, if any.")
    submission_id: str | None = Field(None, description="Set once the upload was completed.")


def is_partial(coverage: float | None) -> bool:
    """A result that covers only part of the scenario set (scored with allow_partial)."""
    return coverage is not None and coverage < 1


class DiskHealth(BaseModel):
    free_bytes: int = Field(description="Free bytes of the data dir's disk.")
    reserved_bytes: int = Field(description="Promised to open uploads and queued or running jobs, not written yet.")
    floor_bytes: int = Field(description="Kept free (WOSAC_MIN_FREE_FRACTION, WOSAC_MIN_FREE_BYTES).")
    refusing_uploads: bool = Field(description="New uploads and chunks get 507 until space is freed.")


class Health(BaseModel):
    status: str = Field(
        description="ok; degraded while uploads are refused for disk space; error when the "
        "database is unreachable (503)."
    )
    database: str
    scenario_shards: int  # the TFRecord files of the scenario set (each holds many scenarios)
    disk: DiskHealth | None = None


def iso(t: float | None) -> str | None:
    if t is None:
        return None
    return datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="milliseconds")


def status_of(row: dict) -> SubmissionStatus:
    report = json.loads(row["report"]) if row.get("report") else None
    return SubmissionStatus(
        id=row["id"],
        state=row["state"],
        method=row["method"],
        challenge=row["challenge"],
        config=row["config"],
        published=bool(row["published"]),
        allow_partial=bool(row["allow_partial"]),
        upload_bytes=row["upload_bytes"],
        progress=Progress(scenarios_done=row["scenarios_done"], scenarios_total=row["scenarios_total"]),
        attempts=row["attempts"],
        created_at=iso(row["created_at"]),
        updated_at=iso(row["updated_at"]),
        started_at=iso(row["started_at"]),
        finished_at=iso(row["finished_at"]),
        error=row["error"],
        validation_report=report,
        realism_meta_metric=row["realism_meta_metric"],
        coverage=row.get("coverage"),
        partial=is_partial(row.get("coverage")),
        results_url=f"/v1/submissions/{row['id']}/results" if row["state"] == "done" else None,
        peak_rss_bytes=row.get("peak_rss_bytes"),
        cpu_s=row.get("cpu_s"),
    )
