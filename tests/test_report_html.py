"""``report.html`` (:mod:`thinfilm.report_html`): the escaping of what users name, and the
report of a small benchmark run in a real browser: Debian's ``chromium`` driven through
``chromedriver`` by selenium, headless and offline.

The browser test loads the report from ``file://``, finds no console error, sorts a
leaderboard and the tasks by a column, filters by method and by scene, opens a task's view
and checks that its figures loaded, and takes a screenshot into its temporary folder. The
screenshot in the documentation, ``docs/report_screenshot.png``, is this test's; regenerate it
with::

    THINFILM_UPDATE_SCREENSHOT=1 .venv/bin/python -m pytest tests/test_report_html.py

``scripts/test.sh`` installs ``chromium`` and ``chromium-driver`` where they are missing; without
them the browser test is skipped.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import pytest
from test_benchmark import FAST

from thinfilm import benchmark

ROOT = Path(__file__).resolve().parents[1]
SCREENSHOT = ROOT / "docs" / "report_screenshot.png"

EVIL_SCENE = "<script>alert(1)</script>"
EVIL_METHOD = 'm"<b>&amp;'


class _Collect(HTMLParser):
    """Every start tag's attributes (values unescaped, as a browser reads them) and the text of
    the scripts and styles."""

    def __init__(self):
        super().__init__()
        self.tags, self.raw, self._in = [], {"script": [], "style": []}, None

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        self._in = tag if tag in self.raw else None

    def handle_endtag(self, tag):
        self._in = None

    def handle_data(self, data):
        if self._in:
            self.raw[self._in].append(data)


def _results_with_user_strings():
    metrics = {k: {"mean": 1.0, "median": 1.0, "p95": 2.0, "max": 3.0}
               for k in ("normal_error_deg", "zenith_error_deg", "thickness_error_nm", "delta_e_ab",
                         "delta_e_2000", "spectral_rmse")}
    metrics.update(film_ior_error=0.01, efficiency_normal=0.5, efficiency_thickness=0.25,
                   crlb_normal_deg={"mean": 0.5, "median": 0.5, "p95": 0.6, "max": 0.7, "rms": 0.5})
    return {
        "suite": {"name": "<i>suite</i>", "description": "<img src=x onerror=alert(2)>"}, "quick": True,
        "resolution": 32, "missing_kinds": {"spectral": "<u>module</u> missing"}, "timings_s": {"total": 3.0},
        "execution": {"mode": "in-process"},
        "scenes": [{"id": EVIL_SCENE, "seed": 0, "resolution": 32, "kinds": ["rgb"], "dataset": "datasets/x"}],
        "rows": [
            {"scene": EVIL_SCENE, "kind": "rgb", "method": EVIL_METHOD, "role": "default", "source": "<s>pkg</s>",
             "metrics": metrics, "coverage": 0.5, "film_ior_estimated": 1.38, "task": "tasks/x/rgb-m",
             "estimate": "tasks/x/rgb-m/estimate", "evaluation": "tasks/x/rgb-m/evaluation",
             "reconstruct_s": 1.0, "evaluate_s": 1.0},
            {"scene": EVIL_SCENE, "kind": "rgb", "method": "b", "role": "other", "task": "tasks/x/rgb-b",
             "error": "RuntimeError: <b>boom</b>", "traceback": "Traceback\n  <script>alert(3)</script>",
             "estimate": "tasks/x/rgb-b/estimate", "evaluation": "tasks/x/rgb-b/evaluation"},
        ],
    }


def test_every_user_string_is_escaped_and_only_the_page_script_runs():
    text = benchmark.write_report_html(_results_with_user_strings())
    for raw in (EVIL_SCENE, "<script>alert(3)", "<img src=x", "<b>boom", "<i>suite", "<u>module", "<s>pkg",
                EVIL_METHOD):
        assert raw not in text, raw
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in text
    assert "RuntimeError: &lt;b&gt;boom&lt;/b&gt;" in text and "m&quot;&lt;b&gt;&amp;amp;" in text
    page = _Collect()
    page.feed(text)
    assert [t for t, _ in page.tags].count("script") == 1
    assert {a["src"] for t, a in page.tags if t == "img"} == {  # the figures, nothing injected
        "datasets/x/preview.png", *(f"tasks/x/rgb-m/evaluation/{n}.png" for n in ("appearance", "normals", "thickness",
                                                                                    "errors", "bound"))}
    # a browser reads the attributes back as the names were given: the filters match
    assert {a["data-scene"] for t, a in page.tags if "data-scene" in a and t == "tr"} == {EVIL_SCENE}
    assert {a["value"] for t, a in page.tags if t == "option"} == {"", EVIL_SCENE, EVIL_METHOD, "b"}
    # the policy runs the page's own script and style, by their hashes, and nothing else
    csp = next(a["content"] for t, a in page.tags if a.get("http-equiv") == "Content-Security-Policy")
    for kind in ("script", "style"):
        digest = base64.b64encode(hashlib.sha256("".join(page.raw[kind]).encode()).digest()).decode()
        assert f"{kind}-src 'sha256-{digest}'" in csp
    assert "default-src 'none'" in csp and "unsafe-inline" not in csp
    # the failed task's view shows the error and its traceback, no figures
    assert "Traceback\n  &lt;script&gt;alert(3)&lt;/script&gt;" in text
    assert "tasks/x/rgb-b/evaluation/appearance.png" not in text
    assert "tasks/x/rgb-m/evaluation/appearance.png" in text


def _browser():
    """Paths of Debian's chromium and chromedriver, or None."""
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    driver = shutil.which("chromedriver") or "/usr/bin/chromedriver"
    return (chromium, driver) if Path(chromium).is_file() and Path(driver).is_file() else None


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """A small in-process benchmark: the pyramid (RGB: ground truth, both RGB methods) and the
    hemisphere (spectral: ground truth, the paper's method), 24 px, 21 bands."""
    root = tmp_path_factory.mktemp("report")
    fast = json.dumps(FAST)
    (root / "suite.toml").write_text(
        'name = "small"\ndescription = "two scenes, two kinds"\n'
        f'[[scenes]]\nname = "pyr"\nspec = "pyramid"\nresolution = 24\nkinds = ["rgb"]\noverrides = {fast}\n'
        f'[[scenes]]\nname = "hemi"\nspec = "hemisphere"\nresolution = 24\nkinds = ["spectral"]\n'
        f"overrides = {fast}\n")
    out = root / "run"
    results = benchmark.run_benchmark(out, suite=root / "suite.toml", methods=["coherent", "paper"], workers=0,
                                      progress=False)
    assert not [r for r in results["rows"] if "error" in r], [r.get("traceback") for r in results["rows"]]
    return out, results


_VISIBLE = ("return Array.from(document.querySelectorAll(arguments[0])).filter(r => r.offsetParent !== null)"
            ".map(r => [r.getAttribute('data-scene'), r.getAttribute('data-method'), "
            "r.cells[arguments[1]] ? r.cells[arguments[1]].getAttribute('data-v') : null])")
_HEADER = ("return Array.from(document.querySelector(arguments[0]).tHead.rows[0].cells)"
           ".findIndex(h => h.textContent.startsWith(arguments[1]))")


@pytest.mark.slow
def test_the_report_of_a_small_run_in_chromium(small_run, tmp_path):
    found = _browser()
    if found is None:
        pytest.skip("Debian's chromium and chromium-driver are not installed (scripts/test.sh installs them)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select, WebDriverWait

    out, results = small_run
    rows = results["rows"]
    assert (out / "report.html").is_file() and (out / "report.md").is_file()
    options = webdriver.ChromeOptions()
    options.binary_location = found[0]
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1280,1400", "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-default-apps", "--disable-sync"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=Service(found[1]))
    logs = []
    try:
        driver.get((out / "report.html").as_uri())
        logs += driver.get_log("browser")
        assert driver.find_element(By.ID, "f-count").text == f"{len(rows)} of {len(rows)} tasks shown"

        # the RGB leaderboard over all scenes, in rank order, then by normal error (twice: descending)
        board = "#board-rgb .board[data-scene=''] table"
        col = driver.execute_script(_HEADER, board, "normal err.")
        ranked = [e["method"] for e in benchmark.leaderboard(results, "rgb")]
        assert [m for _, m, _ in driver.execute_script(_VISIBLE, board + " tbody tr", col)] == ranked
        head = driver.find_element(By.CSS_SELECTOR, board).find_elements(By.TAG_NAME, "th")[col]
        head.click()
        head.click()
        assert head.get_attribute("aria-sort") == "descending"
        shown = driver.execute_script(_VISIBLE, board + " tbody tr", col)
        means = {e["method"]: e["normal_error_deg"] for e in benchmark.leaderboard(results, "rgb")}
        assert [m for _, m, _ in shown] == sorted(means, key=means.get, reverse=True) != ranked
        assert [float(v) for _, _, v in shown] == pytest.approx(sorted(means.values(), reverse=True))

        # the tasks by ΔE*ab: ascending, then descending
        col = driver.execute_script(_HEADER, "#task-table", "ΔE*ab")
        by_de = [(r["scene"], r["method"]) for r in sorted(rows, key=lambda r: r["metrics"]["delta_e_ab"]["mean"])]
        for order in (by_de, by_de[::-1]):
            driver.find_elements(By.CSS_SELECTOR, "#task-table th")[col].click()
            shown = [(s, m) for s, m, _ in driver.execute_script(_VISIBLE, "#task-table tbody tr", col)]
            assert shown == order
        assert shown != [(r["scene"], r["method"]) for r in rows]

        # filters: one method, then one scene
        Select(driver.find_element(By.ID, "f-method")).select_by_value("coherent")
        assert [(s, m) for s, m, _ in driver.execute_script(_VISIBLE, "#task-table tbody tr", 0)] == [
            ("pyr", "coherent")]
        assert [m for _, m, _ in driver.execute_script(_VISIBLE, "#board-rgb tbody tr", 0)] == ["coherent"]
        assert driver.find_element(By.CSS_SELECTOR, "#board-spectral .empty").is_displayed()
        assert driver.find_element(By.ID, "f-count").text == f"1 of {len(rows)} tasks shown"
        Select(driver.find_element(By.ID, "f-method")).select_by_value("")
        Select(driver.find_element(By.ID, "f-scene")).select_by_value("hemi")
        assert sorted(m for _, m, _ in driver.execute_script(_VISIBLE, "#task-table tbody tr", 0)) == [
            "ground truth", "kobayashi"]
        assert driver.find_element(By.CSS_SELECTOR, "#board-rgb .empty").is_displayed()
        assert [m for _, m, _ in driver.execute_script(_VISIBLE, "#board-spectral tbody tr", 0)] == ["kobayashi"]
        assert driver.find_element(By.CSS_SELECTOR, "#board-spectral .board[data-scene='hemi']").is_displayed()
        Select(driver.find_element(By.ID, "f-scene")).select_by_value("")

        # a task's view: its figures, every one loaded
        driver.find_element(By.CSS_SELECTOR, "#task-table tr[data-scene='hemi'][data-method='kobayashi'] a").click()
        task = next(r for r in rows if r["scene"] == "hemi" and r["method"] == "kobayashi")
        view = driver.find_element(By.CSS_SELECTOR, ".task:target")
        assert view.is_displayed() and "hemi — kobayashi" in view.text
        images = view.find_elements(By.TAG_NAME, "img")
        WebDriverWait(driver, 30).until(lambda d: all(d.execute_script("return arguments[0].complete", i)
                                                      for i in images))
        loaded = {Path(i.get_attribute("src")).name: driver.execute_script("return arguments[0].naturalWidth", i)
                  for i in images}
        assert set(loaded) == {"preview.png", "appearance.png", "normals.png", "thickness.png", "errors.png",
                               "bound.png"}
        assert all(w > 0 for w in loaded.values()), loaded
        assert all((out / task["evaluation"] / n).is_file() for n in loaded if n != "preview.png")
        assert re.search(r"efficiency_thickness \d", view.text)

        # the screenshot: the task's view above the leaderboards
        driver.set_window_size(1280, min(2400, driver.execute_script("return document.body.scrollHeight") + 140))
        driver.execute_script("window.scrollTo(0, 0)")
        shot = tmp_path / "report_screenshot.png"
        assert driver.save_screenshot(str(shot)) and shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        logs += driver.get_log("browser")
    finally:
        driver.quit()
    assert not [e for e in logs if e["level"] == "SEVERE"], logs
    assert not [e for e in logs if "Content Security Policy" in e["message"]], logs
    if os.environ.get("THINFILM_UPDATE_SCREENSHOT") == "1":
        shutil.copyfile(shot, SCREENSHOT)
