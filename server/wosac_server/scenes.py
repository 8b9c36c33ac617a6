"""A scored submission's scenes: the pictured worst ones (`results/<id>.scenes/`, drawn by the worker)
and any scene of its result by its row, with the objects that cost it most (`scene_objects`).

Shared by the JSON API (`/v1/submissions/{id}/scenes`, `/v1/submissions/{id}/results/scenarios/{row}`)
and the web pages (`web.py`). Who may see them is decided by their callers: the submission's key, or
anyone for a submission its leaderboard shows (`jobs.is_public`).
"""

from __future__ import annotations

import json
from pathlib import Path

from .errors import Gone, NotFound
from .scene_objects import scene_records
from .settings import Settings

WORST_OBJECTS = 5


def scene_index(settings: Settings, submission_id: str) -> list[dict]:
    """The pictured scenes (scenes.json), worst first; [] when none were drawn."""
    path = settings.scenes_dir(submission_id) / "scenes.json"
    if not path.is_file():
        return []
    with open(path) as f:
        scenes = json.load(f)["scenes"]
    for entry in scenes:  # drawn by an earlier version: no objects, no row
        entry.setdefault("worst_objects", [])
        entry.setdefault("object_picture", False)
    return scenes


def picture_path(settings: Settings, submission_id: str, rank: int, of_object: bool = False) -> Path:
    """A picture of `scene_index` by rank: the scene, or its worst object; `NotFound` when there is none, `Gone`
    when its file is gone."""
    entry = next((e for e in scene_index(settings, submission_id) if e["rank"] == rank), None)
    if entry is None or (of_object and not entry["object_picture"]):
        what = "object picture" if of_object else "scene picture"
        raise NotFound(f"submission {submission_id} has no {what} {rank}")
    picture = settings.scenes_dir(submission_id) / (f"{rank}.object.png" if of_object else f"{rank}.png")
    if not picture.is_file():
        raise Gone(f"picture {rank} of submission {submission_id} is missing on the server")
    return picture


def scene_detail(settings: Settings, submission: dict, row: int, total: int, rows: list[str]) -> dict:
    """One scene of a done submission's result, from the page of its result at `row` (`total` rows; `rows`
    the JSON text of that one, or none past the end): its row, its worst objects (from the job's
    per-object file; [] for a job scored without one) and its pictures when it is one of the pictured
    scenes. `NotFound` past the last row."""
    submission_id = submission["id"]
    if not rows:
        raise NotFound(f"submission {submission_id} has {total} scenes (rows 0 to {total - 1})")
    scenario = json.loads(rows[0])
    records = scene_records(settings.objects_path(submission_id), settings.objects_index_path(submission_id), row)
    worst = []
    if records:
        # Imported here: it loads the scoring stack (features, k-d trees), kept out of the API process's start
        # (server_api_test: the API starts without it) until a scene page asks.
        from wosac_eval.results.worst_objects import scene_worst_objects

        worst = scene_worst_objects(records, scenario, submission["config"], WORST_OBJECTS)
    pictured = next((e for e in scene_index(settings, submission_id) if e.get("row") == row), None)
    return {
        "row": row,
        "total": total,
        "scenario": scenario,
        "objects": None if records is None else len(records),
        "worst_objects": worst,
        "picture": None
        if pictured is None
        else {"rank": pictured["rank"], "object_picture": pictured["object_picture"]},
    }
