"""The small web page: leaderboard, upload form, a submission's status.

Server-rendered from the templates beside this file with `string.Template`
(every value HTML-escaped here); no external CDN, no build step. The upload and
status forms talk to the same `/v1` API with the user's key, kept in the tab's
sessionStorage only.
"""

import html
import re
from pathlib import Path
from string import Template

from fastapi import FastAPI, HTTPException
from fastapi.responses import HTMLResponse, Response

from . import jobs
from .db import Store
from .settings import Settings

TEMPLATES = Path(__file__).with_name("templates")
BUCKET_COLUMNS = [
    ("kinematic_metrics", "Kinematic"),
    ("interactive_metrics", "Interactive"),
    ("map_based_metrics", "Map-based"),
    ("min_ade", "minADE"),
]


def _template(name: str) -> Template:
    return Template((TEMPLATES / name).read_text())


def _page(title: str, content: str) -> str:
    return _template("base.html").substitute(title=html.escape(title), content=content)


def _num(value) -> str:
    return "–" if value is None else f"{value:.4f}"


def leaderboard_table(entries: list[dict]) -> str:
    if not entries:
        return '<p class="empty">No published results yet for this config.</p>'
    head = "".join(f'<th class="num">{html.escape(label)}</th>' for _, label in BUCKET_COLUMNS)
    rows = []
    for e in entries:
        cells = "".join(f'<td class="num">{_num(e["buckets"].get(k))}</td>' for k, _ in BUCKET_COLUMNS)
        rows.append(f'<tr><td class="num">{e["rank"]}</td><td class="method">{html.escape(e["method"])}</td>'
                    f'<td class="num meta">{_num(e["realism_meta_metric"])}</td>{cells}</tr>')
    return ('<table id="leaderboard-table"><thead><tr><th class="num">#</th><th>Method</th>'
            f'<th class="num">Realism meta-metric</th>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table>')


def install_pages(app: FastAPI, store: Store, settings: Settings) -> None:
    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def index(config: str = "2025"):
        if config not in settings.configs:
            config = settings.configs[0]
        options = "".join(
            f'<option value="{html.escape(c)}"{" selected" if c == config else ""}>{html.escape(c)}</option>'
            for c in settings.configs)
        content = _template("index.html").substitute(
            config=html.escape(config), config_options=options,
            table=leaderboard_table(jobs.leaderboard(store, config)))
        return _page("Leaderboard", content)

    @app.get("/submissions/{submission_id}", response_class=HTMLResponse, include_in_schema=False)
    def submission_page(submission_id: str):
        # The page is a shell; its script fetches the status with the user's key.
        if not re.fullmatch(r"[0-9a-f]{32}", submission_id):
            raise HTTPException(404, "not a submission id")
        content = _template("submission.html").substitute(submission_id=submission_id)
        return _page(f"Submission {submission_id}", content)

    @app.get("/static/style.css", include_in_schema=False)
    def style():
        return Response((TEMPLATES / "style.css").read_text(), media_type="text/css",
                        headers={"Cache-Control": "max-age=300"})
