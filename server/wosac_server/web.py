"""The small web page: leaderboard, upload form, a submission's status.

Server-rendered from the templates beside this file with `string.Template`
(every value HTML-escaped here); no external CDN, no build step. The upload and
status forms talk to the same `/v1` API with the user's key, kept in the tab's
sessionStorage only.
"""

import base64
import hashlib
import html
import re
from pathlib import Path
from string import Template

from fastapi import FastAPI, HTTPException
from fastapi.responses import HTMLResponse, Response

from wosac_eval.challenges import CHALLENGE_NAMES
from wosac_eval.metrics.config import default_config, preset_fits

from . import jobs
from .models import is_partial

TEMPLATES = Path(__file__).with_name("templates")
BUCKET_COLUMNS = [
    ("kinematic_metrics", "Kinematic"),
    ("interactive_metrics", "Interactive"),
    ("map_based_metrics", "Map-based"),
    ("min_ade", "minADE"),
]


def _template(name: str) -> Template:
    return Template((TEMPLATES / name).read_text())


_SCRIPT = re.compile(r"<script>(.*?)</script>", re.S)


def security_headers(page: str) -> dict:
    """Headers of an HTML page: a CSP that allows only this page's own inline scripts (by hash) and
    same-origin requests, no framing, no MIME sniffing."""
    hashes = " ".join(f"'sha256-{base64.b64encode(hashlib.sha256(body.encode()).digest()).decode()}'"
                      for body in _SCRIPT.findall(page))
    script_src = hashes or "'none'"
    policy = (f"default-src 'none'; script-src {script_src}; style-src 'self'; "
              "img-src 'self' data: blob:; connect-src 'self'; form-action 'self'; base-uri 'none'; "
              "frame-ancestors 'none'")
    return {"Content-Security-Policy": policy, "X-Frame-Options": "DENY", "X-Content-Type-Options": "nosniff",
            "Referrer-Policy": "no-referrer"}


def _page(title: str, content: str) -> HTMLResponse:
    page = _template("base.html").substitute(title=html.escape(title), content=content)
    return HTMLResponse(page, headers=security_headers(page))


def _num(value) -> str:
    return "–" if value is None else f"{value:.4f}"


TITLES = {"sim_agents": "Sim agents", "scenario_gen": "Scenario generation"}


def _coverage(value) -> str:
    """A result's share of the scenario set; partial results are marked."""
    if value is None:
        return "–"
    text = f"{100 * value:.1f}%"
    if not is_partial(value):
        return text
    return f'<span class="partial" title="scored with allow_partial on part of the scenario set">{text} partial</span>'


def leaderboard_table(entries: list[dict], table_id: str = "leaderboard-table") -> str:
    if not entries:
        return '<p class="empty">No published results yet for this config.</p>'
    head = "".join(f'<th class="num">{html.escape(label)}</th>' for _, label in BUCKET_COLUMNS)
    rows = []
    for e in entries:
        cells = "".join(f'<td class="num">{_num(e["buckets"].get(k))}</td>' for k, _ in BUCKET_COLUMNS)
        rows.append(f'<tr><td class="num">{e["rank"]}</td><td class="method">{html.escape(e["method"])}</td>'
                    f'<td class="num meta">{_num(e["realism_meta_metric"])}</td>{cells}'
                    f'<td class="num">{_coverage(e.get("coverage"))}</td></tr>')
    return (f'<table id="{table_id}"><thead><tr><th class="num">#</th><th>Method</th>'
            f'<th class="num">Realism meta-metric</th>{head}<th class="num">Coverage</th></tr></thead>'
            f'<tbody>{"".join(rows)}</tbody></table>')


def configs_of(challenge: str, configs: list[str]) -> list[str]:
    """The served configs a challenge may be scored with (its presets and any textproto)."""
    return [c for c in configs if preset_fits(c, challenge)]


def _board_config(challenge: str, asked: str | None, configs: list[str]) -> str | None:
    usable = configs_of(challenge, configs)
    if asked in usable:
        return asked
    preferred = default_config(challenge)
    return preferred if preferred in usable else (usable[0] if usable else None)


def install_pages(app: FastAPI, svc) -> None:
    store, settings = svc.store, svc.settings

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def index(config: str | None = None):
        boards = []
        for challenge in CHALLENGE_NAMES:
            chosen = _board_config(challenge, config, settings.configs)
            if chosen is None:
                continue
            options = "".join(f'<option value="{html.escape(c)}"{" selected" if c == chosen else ""}>'
                              f'{html.escape(c)}</option>' for c in configs_of(challenge, settings.configs))
            boards.append(
                f'<section id="leaderboard-{challenge}" class="leaderboard"><h1>{TITLES[challenge]} '
                f'<small>config {html.escape(chosen)}</small></h1>'
                f'<form method="get" action="/" class="inline"><label>Config <select name="config">{options}'
                f'</select></label> <button type="submit">Show</button></form>'
                + leaderboard_table(jobs.leaderboard(store, chosen, challenge),
                                    "leaderboard-table" if challenge == "sim_agents" else f"leaderboard-{challenge}-table")
                + "</section>")
        config_options = '<option value="">(the challenge\'s current one)</option>' + "".join(
            f'<option value="{html.escape(c)}">{html.escape(c)}</option>' for c in settings.configs)
        challenge_options = "".join(f'<option value="{c}">{TITLES[c]}</option>' for c in CHALLENGE_NAMES)
        content = _template("index.html").substitute(leaderboards="".join(boards), config_options=config_options,
                                                     challenge_options=challenge_options)
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
                        headers={"Cache-Control": "max-age=300", "X-Content-Type-Options": "nosniff"})
