import base64
import html.parser
import io
import json

import numpy as np
import pytest
from PIL import Image

from support import browser
from wosac_eval.results.compare import compare_results
from wosac_eval.results.stats import PairedSettings
from wosac_eval.results.report import SECTIONS, render_report
from wosac_eval.scoring.result_reader import load_result
from wosac_eval.results.synthetic_results import WEIGHTS_2025, result_json, synthetic_scenarios

FAST = PairedSettings(n_boot=300, n_perm=300)


class _Page(html.parser.HTMLParser):
    """Collects section ids, resource references, images and the worst-scenario tables of a page."""

    def __init__(self, text):
        super().__init__()
        self.sections, self.refs, self.images, self.tags = [], [], [], set()
        self.worst: dict[str, list[str]] = {}
        self._metric = None
        self._in_code = False
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.tags.add(tag)
        if tag == "section":
            self.sections.append(attrs.get("id"))
        for key in ("src", "href", "srcset", "action", "poster"):
            if key in attrs:
                self.refs.append(attrs[key])
        if tag == "img":
            self.images.append(attrs["src"])
        if tag == "details":
            self._metric = attrs.get("data-metric")
            self.worst[self._metric] = []
        self._in_code = tag == "code"

    def handle_endtag(self, tag):
        if tag == "details":
            self._metric = None
        if tag == "code":
            self._in_code = False

    def handle_data(self, data):
        if self._metric and self._in_code:
            self.worst[self._metric].append(data)


def _results(tmp_path, weights=None):
    scenarios = synthetic_scenarios(200, seed=0)
    scenarios[17]["metametric"] = 0.001  # the worst scenario by the meta-metric
    scenarios[42]["simulated_collision_rate"] = 0.99  # the worst by collisions (higher is worse)
    scenarios[5]["scenario_id"] = "<b>odd&id</b>"
    skipped = [{"scenario_id": "s-skip", "reason": "no objects to evaluate <at all>"}]
    base_path, new_path = tmp_path / "base.json", tmp_path / "new.json"
    base_path.write_text(json.dumps(result_json(synthetic_scenarios(200, seed=0, shift={"metametric": -0.01}))))
    new_path.write_text(json.dumps(result_json(scenarios, skipped=skipped)))
    load = lambda p: load_result(p, weights_for=lambda config: weights)
    return load(new_path), load(base_path)


@pytest.fixture(scope="module")
def with_baseline(tmp_path_factory):
    """(path, html) of a report compared with a baseline; buckets only as aggregates."""
    tmp_path = tmp_path_factory.mktemp("report")
    result, base = _results(tmp_path)
    page = render_report(result, base=base, comparison=compare_results(base, result, settings=FAST), top_k=5)
    path = tmp_path / "report.html"
    path.write_text(page, encoding="utf-8")
    return path, page


@pytest.fixture(scope="module")
def alone(tmp_path_factory):
    """The html of a report without baseline, with per-scenario buckets (the 2025 weights)."""
    result, _ = _results(tmp_path_factory.mktemp("alone"), weights=WEIGHTS_2025)
    return render_report(result, top_k=5)


def _assert_report_structure(page: _Page, with_comparison: bool):
    expected = [s for s in SECTIONS if with_comparison or s != "comparison"]
    assert sorted(page.sections) == sorted(expected)
    assert page.worst["metametric"][0] == "scn000017"
    assert page.worst["simulated_collision_rate"][0] == "scn000042"
    assert all(len(v) == 5 for v in page.worst.values())


def test_report_sections_and_worst_scenarios(with_baseline):
    _, text = with_baseline
    _assert_report_structure(_Page(text), with_comparison=True)
    assert "better" in text  # the metametric verdict
    # Scenario 17's meta-metric was set to 0.001 in the new run: the largest drop against the baseline.
    drops = text[text.index('data-changes="drops"') :]
    assert drops[drops.index("<code>") + 6 :].startswith("scn000017</code>")


def test_report_without_baseline_has_no_comparison_and_plots_buckets(alone):
    page = _Page(alone)
    _assert_report_structure(page, with_comparison=False)
    assert {"kinematic_metrics", "interactive_metrics", "map_based_metrics"} <= set(page.worst)


def test_report_is_self_contained_with_valid_embedded_pngs(with_baseline):
    _, text = with_baseline
    page = _Page(text)
    assert "script" not in page.tags and "link" not in page.tags and "iframe" not in page.tags
    assert page.refs and all(r.startswith("data:image/png;base64,") for r in page.refs)
    assert "http://" not in text and "https://" not in text and "url(" not in text
    assert len(page.images) == 5  # buckets, rates, forest, scatter, distributions
    for src in page.images:
        image = Image.open(io.BytesIO(base64.b64decode(src.split(",", 1)[1])))
        assert image.format == "PNG" and image.size[0] > 100 and image.size[1] > 100


def test_report_escapes_ids_and_reasons(with_baseline):
    _, text = with_baseline
    assert "<b>" not in text
    assert "&lt;b&gt;odd&amp;id&lt;/b&gt;" in text
    assert "no objects to evaluate &lt;at all&gt;" in text


def test_render_requires_baseline_and_comparison_together(tmp_path):
    result, base = _results(tmp_path)
    with pytest.raises(ValueError, match="both"):
        render_report(result, base=base)


# ------------------------------------------------------------------------------------------------
# In a real browser


def _require_chromium():
    if browser.find_chromium() is None:
        pytest.skip("chromium is not installed (apt-get install chromium); CI installs it")


@pytest.mark.browser
def test_report_renders_in_headless_chromium(with_baseline):
    _require_chromium()
    path, _ = with_baseline
    dom = browser.dump_dom(path)
    page = _Page(dom)
    _assert_report_structure(page, with_comparison=True)
    headings = [
        h
        for h in (
            "Headline score",
            "Buckets",
            "Collision, offroad and red-light rates",
            "Per-scenario distributions",
            "Worst scenarios per metric",
            "Comparison with the baseline",
            "Skipped scenarios",
        )
        if h in dom
    ]
    assert len(headings) == 7


@pytest.mark.browser
def test_report_screenshot_shows_content(with_baseline, tmp_path):
    _require_chromium()
    path, _ = with_baseline
    png = browser.screenshot(path, tmp_path / "shot.png", width=1280, height=2000)
    with Image.open(png) as image:
        assert image.size == (1280, 2000)
        pixels = np.asarray(image.convert("L"), dtype=np.float64)
    # A page with text, tables and plots: many dark pixels and a wide spread, not a blank or error page.
    assert pixels.std() > 20
    assert (pixels < 100).mean() > 0.005


def test_report_of_a_result_where_every_scenario_was_skipped():
    # What `score --partial` writes when nothing could be scored: no scenarios, NaN aggregates.
    from wosac_eval.scoring.result_reader import parse_result

    result = parse_result(
        {
            "config": "2025",
            "scenarios": [],
            "aggregate": {"metametric": float("nan")},
            "buckets": {"realism_meta_metric": float("nan")},
            "skipped": [{"scenario_id": "s1", "reason": "invalid rollouts"}],
        },
        "empty.json",
    )
    text = render_report(result)
    page = _Page(text)
    assert sorted(page.sections) == sorted(s for s in SECTIONS if s != "comparison")
    assert "No scenarios." in text and "invalid rollouts" in text and "Skipped scenarios (1)" in text


@pytest.mark.parametrize("num_scenarios", [1, 2])
def test_histogram_axis_of_one_scenario_reads_plain_numbers(tmp_path, monkeypatch, num_scenarios):
    # One scenario (or all values equal) used to give bins of width 1e-6 and an axis reading
    # '1e-6+2.5824e-1'; the span is now readable and the axis never uses an offset.
    from wosac_eval.results import report_plots

    scenarios = synthetic_scenarios(num_scenarios, seed=0)
    for s in scenarios:
        s["metametric"] = 0.25824
    path = tmp_path / "one.json"
    path.write_text(json.dumps(result_json(scenarios)))
    result = load_result(path)
    figures = []

    def keep(fig, tight=True):
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig).draw()  # as png draws it: tick labels and offset text set
        figures.append(fig)
        return ""

    monkeypatch.setattr(report_plots, "png", keep)
    report_plots.distribution_plot(result, None, ["metametric", "linear_speed_likelihood"])
    (fig,) = figures
    for ax in fig.axes:
        assert ax.xaxis.get_offset_text().get_text() == ""
        labels = [t.get_text().replace("\u2212", "-") for t in ax.get_xticklabels() if t.get_text()]
        assert labels and all("e" not in label for label in labels), labels
        low, high = ax.get_xlim()
        assert high - low > 1e-3
    bins = report_plots._histogram_bins(np.array([0.25824]))
    assert bins[0] < 0.25824 < bins[-1] and bins[-1] - bins[0] == pytest.approx(0.025824)
