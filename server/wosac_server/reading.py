"""The service layer's reading side: a key's submissions, their stored results and scenes, the leaderboards.

Every rule about who sees what and when lives here (another key's id is `NotFound`, results before
`done` are a `Conflict`, a result missing or damaged on the server's disk is `Gone`, said once for
every route that reads one); the routes only shape the answers.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Request

from . import auth, jobs, results, scenes
from .errors import Conflict, Gone
from .service import Service
from .settings import Settings


def reading_of(request: Request) -> Reading:
    """The dependency of the routes that read."""
    return request.app.state.reading


MAX_PAGE = results.MAX_PAGE  # rows in one page of /results/scenarios


class Reading:
    """What a key (or anyone, for the leaderboards) may read, through one `Service`."""

    def __init__(self, svc: Service):
        self.svc = svc

    def submissions(self, key: auth.ApiKey, limit: int) -> list[dict]:
        """The key's submissions, newest first."""
        return jobs.list_submissions(self.svc.store, key.id, limit)

    def leaderboard(self, challenge: str, config: str | None) -> tuple[str, list[dict]]:
        """(the config shown, its best published result per method); public."""
        config = self.svc.config_for(challenge, config)
        return config, jobs.leaderboard(self.svc.store, config, challenge)

    def done(self, key: auth.ApiKey, submission_id: str, what: str = "scenes") -> dict:
        """The key's submission once it is done (`Conflict` before, saying why when it failed)."""
        row = self.svc.own_submission(key, submission_id)
        if row["state"] == "failed" and what == "results":
            raise Conflict(f"submission {submission_id} failed: {row['error']}")
        if row["state"] != "done":
            raise Conflict(f"submission {submission_id} is {row['state']}; {what} exist once it is done")
        return row

    def stored_result(self, key: auth.ApiKey, submission_id: str) -> results.StoredResult:
        """The submission's stored result, opened (its files stay readable while it is sent)."""
        self.done(key, submission_id, "results")
        return open_stored(self.svc.settings.results_dir, submission_id)

    def scenes(self, key: auth.ApiKey, submission_id: str) -> list[dict]:
        """The pictured worst scenes of a done submission, worst first."""
        self.done(key, submission_id)
        return scenes.scene_index(self.svc.settings, submission_id)

    def picture(self, key: auth.ApiKey, submission_id: str, rank: int, of_object: bool) -> Path:
        self.done(key, submission_id)
        return scenes.picture_path(self.svc.settings, submission_id, rank, of_object)

    def scene(self, key: auth.ApiKey, submission_id: str, row: int) -> dict:
        return scene_of(self.svc.settings, self.done(key, submission_id), row)


def scene_of(settings: Settings, submission: dict, row: int) -> dict:
    """One scene of a done submission's result by its row, with its worst objects (`scenes.scene_detail`);
    for a caller that decided who may see it."""
    stored = open_stored(settings.results_dir, submission["id"])
    total, rows = reading(stored, submission["id"], lambda s: s.page(row, 1))
    return scenes.scene_detail(settings, submission, row, total, rows)


def open_stored(results_dir: Path, submission_id: str) -> results.StoredResult:
    """A done submission's stored result, opened; `Gone` when it is missing or damaged on the disk."""
    try:
        stored = results.open_result(results_dir, submission_id)
    except results.ResultDamaged as exc:
        raise damaged(submission_id, exc) from None
    if stored is None:
        raise Gone(
            f"the result file of submission {submission_id} is missing on the server; "
            "ask its operator to restore it (or submit again)"
        )
    return stored


def damaged(submission_id: str, exc: Exception) -> Gone:
    """The one refusal of a result whose files are not as written (found when opened, or while read)."""
    return Gone(
        f"the result file of submission {submission_id} is damaged on the server ({exc}); "
        "ask its operator to restore it (or submit again)"
    )


def reading(stored: results.StoredResult, submission_id: str, read):
    """`read(stored)`, with a result found damaged while read refused as `damaged`; the files are closed."""
    try:
        return read(stored)
    except results.ResultDamaged as exc:
        raise damaged(submission_id, exc) from exc
    finally:
        stored.close()


def readable_csv(stored: results.StoredResult, submission_id: str) -> Iterator[bytes]:
    """The CSV's pieces; its columns are read now, so a damaged result is refused before a byte is sent."""
    try:
        return stored.csv()
    except results.ResultDamaged as exc:
        stored.close()
        raise damaged(submission_id, exc) from exc


def sent_then_closed(stored: results.StoredResult, chunks: Iterator[bytes]) -> Iterator[bytes]:
    """`chunks`, then the result's files closed, whether the answer was sent whole or not."""
    try:
        yield from chunks
    finally:
        stored.close()


def summary_text(stored: results.StoredResult, submission_id: str) -> str:
    """The document without its rows, as JSON text (NaN as the result JSON writes it)."""
    return json.dumps(reading(stored, submission_id, lambda s: s.summary()), allow_nan=True)


def page_text(stored: results.StoredResult, submission_id: str, offset: int, limit: int) -> str:
    """A page of rows as `{"total", "offset", "scenarios"}` JSON: the rows' text as stored, not decoded."""
    total, rows = reading(stored, submission_id, lambda s: s.page(offset, limit))
    return f'{{"total": {total}, "offset": {offset}, "scenarios": [{", ".join(rows)}]}}'


ReadingDep = Annotated[Reading, Depends(reading_of)]
