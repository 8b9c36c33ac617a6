"""The small web page: leaderboard, upload form, a submission's status.

Server-rendered from the templates beside this file with `string.Template`
(every value HTML-escaped here); no external CDN, no build step. The upload form
sends the file through tus (`/v1/uploads`, with tus-js-client served from the package), the
status forms talk to the same `/v1` API; the user's key is kept in the tab's sessionStorage only.
"""

import base64
import hashlib
import html
import re
from pathlib import Path
from string import Template

from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import FileResponse, HTMLResponse, Response
from fastapi.security import HTTPAuthorizationCredentials

from wosac_eval.challenges import CHALLENGE_NAMES
from wosac_eval.metrics.config import default_config, preset_fits

from . import jobs, scenes
from .models import is_partial
from .reading import scene_of

TEMPLATES = Path(__file__).with_name("templates")
VENDORED = Path(__file__).with_name("static")
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
    hashes = " ".join(
        f"'sha256-{base64.b64encode(hashlib.sha256(body.encode()).digest()).decode()}'"
        for body in _SCRIPT.findall(page)
    )
    script_src = f"'self' {hashes}".strip()  # the page's own inline scripts, and /static/tus.min.js
    policy = (
        f"default-src 'none'; script-src {script_src}; style-src 'self'; "
        "img-src 'self' data: blob:; connect-src 'self'; form-action 'self'; base-uri 'none'; "
        "frame-ancestors 'none'"
    )
    return {
        "Content-Security-Policy": policy,
        "X-Frame-Options": "DENY",
        "X-Content-Type-Options": "nosniff",
        "Referrer-Policy": "no-referrer",
    }


def _page(title: str, content: str) -> HTMLResponse:
    page = _template("base.html").substitute(title=html.escape(title), content=content)
    return HTMLResponse(page, headers=security_headers(page))


def _num(value) -> str:
    return "–" if value is None else f"{value:.4f}"


ID = re.compile(r"[0-9a-f]{32}")
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
        rows.append(
            f'<tr><td class="num">{e["rank"]}</td><td class="method">{html.escape(e["method"])}</td>'
            f'<td class="num meta">{_num(e["realism_meta_metric"])}</td>{cells}'
            f'<td class="num">{_coverage(e.get("coverage"))}</td>{_scenes_cell(e.get("submission_id"))}</tr>'
        )
    return (
        f'<table id="{table_id}"><thead><tr><th class="num">#</th><th>Method</th>'
        f'<th class="num">Realism meta-metric</th>{head}<th class="num">Coverage</th><th>Scenes</th></tr></thead>'
        f"<tbody>{''.join(rows)}</tbody></table>"
    )


def _scenes_cell(submission_id) -> str:
    """The row's link to its submission's worst scenes (public for a leaderboard's rows)."""
    if not isinstance(submission_id, str) or not ID.fullmatch(submission_id):
        return "<td></td>"
    return f'<td><a class="scenes" href="/submissions/{submission_id}/scenes">worst scenes</a></td>'


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
            options = "".join(
                f'<option value="{html.escape(c)}"{" selected" if c == chosen else ""}>{html.escape(c)}</option>'
                for c in configs_of(challenge, settings.configs)
            )
            boards.append(
                f'<section id="leaderboard-{challenge}" class="leaderboard"><h1>{TITLES[challenge]} '
                f"<small>config {html.escape(chosen)}</small></h1>"
                f'<form method="get" action="/" class="inline"><label>Config <select name="config">{options}'
                f'</select></label> <button type="submit">Show</button></form>'
                + leaderboard_table(
                    jobs.leaderboard(store, chosen, challenge),
                    "leaderboard-table" if challenge == "sim_agents" else f"leaderboard-{challenge}-table",
                )
                + "</section>"
            )
        config_options = '<option value="">(the challenge\'s current one)</option>' + "".join(
            f'<option value="{html.escape(c)}">{html.escape(c)}</option>' for c in settings.configs
        )
        challenge_options = "".join(f'<option value="{c}">{TITLES[c]}</option>' for c in CHALLENGE_NAMES)
        content = _template("index.html").substitute(
            leaderboards="".join(boards), config_options=config_options, challenge_options=challenge_options
        )
        return _page("Leaderboard", content)

    @app.get("/submissions/{submission_id}", response_class=HTMLResponse, include_in_schema=False)
    def submission_page(submission_id: str):
        # The page is a shell; its script fetches the status with the user's key.
        if not re.fullmatch(r"[0-9a-f]{32}", submission_id):
            raise HTTPException(404, "not a submission id")
        content = _template("submission.html").substitute(submission_id=submission_id)
        return _page(f"Submission {submission_id}", content)

    @app.get("/static/tus.min.js", include_in_schema=False)
    def tus_client():
        """tus-js-client, the tus protocol's own browser client (vendored: static/tus-js-client/README.md)."""
        return FileResponse(
            VENDORED / "tus-js-client" / "tus.min.js",
            media_type="text/javascript",
            headers={"Cache-Control": "max-age=3600", "X-Content-Type-Options": "nosniff"},
        )

    @app.get("/static/style.css", include_in_schema=False)
    def style():
        return Response(
            (TEMPLATES / "style.css").read_text(),
            media_type="text/css",
            headers={"Cache-Control": "max-age=300", "X-Content-Type-Options": "nosniff"},
        )


# -- a submission's scenes --------------------------------------------------------------------------
# /submissions/<id>/scenes (its pictured worst scenes) and /submissions/<id>/scenes/<row> (any scene of its
# result, with its worst objects) are seen as its leaderboard row is for a submission the leaderboard shows
# (jobs.is_public: anyone, no key), else as its results are (the key that uploaded it). Without a key the
# page of a private (or unknown) id is a shell whose script asks for the key and fetches the same page's
# content with it (?fragment=1, `Authorization: Bearer`); the pictures likewise.
def _viewer(svc, request: Request, submission_id: str) -> tuple[dict | None, bool]:
    """(the submission, whether it is seen by anyone), or (None, False) when a key is needed and none was
    sent. 404 for an id another key owns and the leaderboard does not show; 401/429 for a bad key."""
    if not ID.fullmatch(submission_id):
        raise HTTPException(404, "not a submission id")
    row = jobs.get_submission(svc.store, submission_id)
    public = row is not None and jobs.is_public(svc.store, row)
    header = request.headers.get("authorization")
    if header is None:
        return (row, True) if public else (None, False)
    scheme, _, credentials = header.partition(" ")
    key = svc.key_for(
        HTTPAuthorizationCredentials(scheme=scheme, credentials=credentials.strip()),
        request.client.host if request.client else "",
    )
    if row is None or (row["key_id"] != key.id and not public):
        raise HTTPException(404, f"no submission {submission_id!r} for this API key")
    if row["state"] != "done":
        raise HTTPException(409, f"submission {submission_id} is {row['state']}; scenes exist once it is done")
    return row, public


def _img(url: str, alt: str, public: bool) -> str:
    """A picture: linked as is on a public page, fetched with the key by the shell's script otherwise."""
    attr = "src" if public else "data-src"
    return f'<img {attr}="{html.escape(url)}" alt="{html.escape(alt)}">'


def _objects_table(worst: list[dict]) -> str:
    if not worst:
        return '<p class="empty">No per-object values for this scene (scored without them, or no object cost it).</p>'
    head = "".join(f'<th class="num">{label}</th>' for _, label in BUCKET_COLUMNS[:3])
    rows = []
    for w in worst:
        cells = "".join(f'<td class="num">{_num(w["buckets"].get(k))}</td>' for k, _ in BUCKET_COLUMNS[:3])
        top = w["fields"][0] if w["fields"] else None
        field = (
            "–"
            if top is None
            else (f"{html.escape(str(top[0]).removesuffix('_likelihood'))} (likelihood {_num(top[1])})")
        )
        rows.append(
            f'<tr><td class="num">{int(w["object_id"])}</td><td>{html.escape(str(w["object_type"]))}</td>'
            f'<td class="num">{_num(w["contribution"])}</td>{cells}<td>{field}</td></tr>'
        )
    return (
        f'<table class="objects" id="worst-objects"><thead><tr><th class="num">Object</th><th>Type</th>'
        f'<th class="num">Part of the gaps</th>{head}<th>Costliest field</th></tr></thead>'
        f"<tbody>{''.join(rows)}</tbody></table>"
        "<p class=\"meta\">An object's part of a bucket is its share of the scene's <code>1 - bucket</code> "
        "(its likelihoods against the scene's, weighted by its counts); the parts of all objects add up to "
        "the gap. Worst first.</p>"
    )


def _about(row: dict) -> str:
    return (
        f"{html.escape(row['method'])}, config {html.escape(row['config'])}, realism meta-metric "
        f"{_num(row['realism_meta_metric'])}"
    )


def scenes_content(svc, row: dict, public: bool) -> str:
    sid = row["id"]
    entries = scenes.scene_index(svc.settings, sid)
    parts = [
        f"<h1>Worst scenes <small>submission <code>{sid}</code></small></h1>",
        f'<p class="meta">{_about(row)}. The lowest meta-metric scenes: map, log (dashed), rollouts 0 to 2, '
        "boxes of rollout 0 at the last event; crosses are collisions, triangles off-road, squares red-light "
        "runs. Each scene's page lists the objects that cost it most.</p>",
    ]
    if not entries:
        parts.append('<p class="empty">No scene pictures were drawn for this submission.</p>')
    for e in entries:
        worst = e["worst_objects"][0] if e["worst_objects"] else None
        about_worst = (
            ""
            if worst is None
            else (
                f"; worst object {int(worst['object_id'])} ({html.escape(str(worst['object_type']))}), "
                f"part of the gaps {_num(worst['contribution'])}"
            )
        )
        link = (
            f'<a href="/submissions/{sid}/scenes/{int(e["row"])}">{html.escape(e["scenario_id"])}</a>'
            if "row" in e
            else html.escape(e["scenario_id"])
        )
        url = f"/submissions/{sid}/pictures/{int(e['rank'])}.png"
        parts.append(
            f'<figure class="scene" data-scenario="{html.escape(e["scenario_id"])}">'
            f"{_img(url, 'scenario ' + e['scenario_id'], public)}"
            f"<figcaption>{link} — meta-metric {_num(e['metametric'])}{about_worst}</figcaption></figure>"
        )
    return "".join(parts)


def scene_content(svc, row: dict, number: int, public: bool) -> str:
    sid = row["id"]
    detail = scene_of(svc.settings, row, number)
    scenario, total = detail["scenario"], detail["total"]
    base = f"/submissions/{sid}/scenes"
    pager = [
        f'<a href="{base}/{number - 1}" rel="prev">previous scene</a>' if number > 0 else "",
        f'<a href="{base}">worst scenes</a>',
        f'<a href="{base}/{number + 1}" rel="next">next scene</a>' if number + 1 < total else "",
    ]
    facts = [("Submission", f"<code>{sid}</code> ({_about(row)})"), ("Meta-metric", _num(scenario.get("metametric")))]
    facts += [(label, _num(scenario[k])) for k, label in BUCKET_COLUMNS if isinstance(scenario.get(k), (int, float))]
    if isinstance(scenario.get("min_average_displacement_error"), (int, float)):
        facts.append(("minADE", _num(scenario["min_average_displacement_error"])))
    facts.append(("Objects evaluated", "–" if detail["objects"] is None else str(detail["objects"])))
    parts = [
        f'<h1>Scene <code id="scenario-id">{html.escape(str(scenario.get("scenario_id")))}</code> '
        f"<small>scene {number + 1} of {total} in the result (row {number})</small></h1>",
        f'<nav class="pager">{"".join(pager)}</nav>',
        "<dl>" + "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in facts) + "</dl>",
    ]
    picture = detail["picture"]
    if picture is not None:
        rank = int(picture["rank"])
        scene_url = f"/submissions/{sid}/pictures/{rank}.png"
        object_url = f"/submissions/{sid}/pictures/{rank}/object.png"
        figures = [
            f"<figure>{_img(scene_url, 'the scene', public)}"
            "<figcaption>The scene: map, log (dashed), rollouts 0 to 2, boxes of rollout 0 at the last event"
            "</figcaption></figure>"
        ]
        if picture["object_picture"] and detail["worst_objects"]:
            oid = int(detail["worst_objects"][0]["object_id"])
            figures.append(
                f"<figure>{_img(object_url, 'object ' + str(oid), public)}"
                f"<figcaption>Its worst object, {oid}: its rollouts against its log, and its features"
                "</figcaption></figure>"
            )
        parts.append(f'<div class="pictures" id="pictures">{"".join(figures)}</div>')
    else:
        parts.append('<p class="empty">Pictures are drawn for the worst scenes only.</p>')
    parts.append("<h2>Worst objects</h2>" + _objects_table(detail["worst_objects"]))
    return "".join(parts)


def install_scene_pages(app: FastAPI, svc) -> None:
    def answer(request: Request, submission_id: str, fragment: bool, title: str, render) -> Response:
        row, public = _viewer(svc, request, submission_id)
        if row is None:
            if fragment:
                raise HTTPException(
                    401, "missing API key: send 'Authorization: Bearer <key>'", headers={"WWW-Authenticate": "Bearer"}
                )
            return _page(title, _template("scene_shell.html").substitute(submission_id=submission_id))
        content = render(row, public and request.headers.get("authorization") is None)
        if fragment:
            return HTMLResponse(content, headers=security_headers(content))
        return _page(title, content)

    @app.get("/submissions/{submission_id}/scenes", response_class=HTMLResponse, include_in_schema=False)
    def scenes_page(request: Request, submission_id: str, fragment: bool = False):
        return answer(
            request,
            submission_id,
            fragment,
            f"Worst scenes of {submission_id}",
            lambda row, public: scenes_content(svc, row, public),
        )

    @app.get("/submissions/{submission_id}/scenes/{row}", response_class=HTMLResponse, include_in_schema=False)
    def scene_page(request: Request, submission_id: str, row: int, fragment: bool = False):
        if not 0 <= row <= 2**62:
            raise HTTPException(404, "no such row (rows start at 0)")
        return answer(
            request,
            submission_id,
            fragment,
            f"Scene {row} of {submission_id}",
            lambda sub, public: scene_content(svc, sub, row, public),
        )

    def picture(request: Request, submission_id: str, rank: int, of_object: bool) -> FileResponse:
        row, _ = _viewer(svc, request, submission_id)
        if row is None:
            raise HTTPException(
                401, "missing API key: send 'Authorization: Bearer <key>'", headers={"WWW-Authenticate": "Bearer"}
            )
        return FileResponse(
            scenes.picture_path(svc.settings, submission_id, rank, of_object),
            media_type="image/png",
            headers={"X-Content-Type-Options": "nosniff", "Cache-Control": "private, max-age=300"},
        )

    @app.get("/submissions/{submission_id}/pictures/{rank}.png", include_in_schema=False)
    def scene_picture(request: Request, submission_id: str, rank: int):
        return picture(request, submission_id, rank, False)

    @app.get("/submissions/{submission_id}/pictures/{rank}/object.png", include_in_schema=False)
    def object_picture(request: Request, submission_id: str, rank: int):
        return picture(request, submission_id, rank, True)
