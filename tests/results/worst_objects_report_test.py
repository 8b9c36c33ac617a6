"""The report's "worst objects" section (a result scored with `score --per-object`): per bucket, the objects
contributing most to its gap from 1, which split that gap exactly; on the demo's synthetic scenes."""

from __future__ import annotations

import html.parser
import json

import pytest

from wosac_eval.fronts.cli import main
from wosac_eval.metrics.registry import BUCKET_MEMBERS
from wosac_eval.results.report import render_report
from wosac_eval.results.worst_objects import worst_objects
from wosac_eval.scoring.result_reader import load_result


class _Page(html.parser.HTMLParser):
    """Section ids, and per bucket (`data-bucket`) the rows of its table as lists of cell texts."""

    def __init__(self, text):
        super().__init__()
        self.sections, self.buckets = [], {}
        self._bucket = self._row = None
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "section":
            self.sections.append(attrs.get("id"))
        if tag == "details" and "data-bucket" in attrs:
            self._bucket = attrs["data-bucket"]
            self.buckets[self._bucket] = []
        if tag == "tr" and self._bucket:
            self._row = []
            self.buckets[self._bucket].append(self._row)

    def handle_endtag(self, tag):
        if tag == "details":
            self._bucket = None
        if tag in ("tr", "details"):
            self._row = None

    def handle_data(self, data):
        if self._bucket and self._row is not None and data.strip():
            self._row.append(data.strip())


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    from wosac_eval.fronts.demo_pipeline import run_demo

    workdir = tmp_path_factory.mktemp("demo")
    run_demo(workdir, num_scenes=6, policies=("constant_velocity",), challenge="sim_agents", log=lambda *a, **k: None)
    output = workdir / "cv.json"
    assert (
        main(
            [
                "score",
                "--scenarios",
                str(workdir / "scenarios"),
                "--submission",
                str(workdir / "submissions" / "constant_velocity.tar.gz"),
                "--per-object",
                "-o",
                str(output),
            ]
        )
        == 0
    )
    return output


def test_contributions_split_each_bucket_gap_exactly(scored):
    result = load_result(scored)
    everything = worst_objects(result, top_k=10**6)
    assert set(everything) == set(BUCKET_MEMBERS)
    for bucket, objects in everything.items():
        gap = 1.0 - result.headline(bucket)
        assert sum(o.contribution for o in objects) == pytest.approx(gap, rel=1e-5), bucket
        assert all(o.fields and o.fields[0][2] >= o.fields[-1][2] for o in objects)
    top = worst_objects(result, top_k=3)
    for bucket, objects in top.items():
        assert objects == everything[bucket][:3]


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_report_renders_the_worst_objects_section(scored, tmp_path, capsys):
    result = load_result(scored)
    page = _Page(render_report(result, top_k=4))
    assert "worst-objects" in page.sections
    worst = worst_objects(result, top_k=4)
    for bucket, rows in page.buckets.items():
        body = rows[1:]  # the header row first
        assert len(body) == len(worst[bucket]) == 4
        for cells, o in zip(body, worst[bucket]):
            assert cells[1:4] == [o.scenario_id, str(o.object_id), o.object_type]
            assert cells[-1].startswith(o.fields[0][0].removesuffix("_likelihood").replace("_", " "))
    # Through the CLI, and without the per-object file: no section (or a note when it went missing).
    html_path = tmp_path / "report.html"
    assert main(["report", str(scored), "--html", str(html_path), "--top", "3"]) == 0
    assert 'id="worst-objects"' in html_path.read_text()
    document = json.loads(scored.read_text())
    plain = tmp_path / "plain.json"
    moved = tmp_path / "moved.json"
    plain.write_text(json.dumps({k: v for k, v in document.items() if k != "per_object"}))
    moved.write_text(json.dumps(document))  # names a file that is not beside it
    assert "worst-objects" not in _Page(render_report(load_result(plain))).sections
    assert "is missing" in render_report(load_result(moved))
