"""report.html in a real browser: headless Chromium (the operating system's, driven by Playwright) opens
the page at 1280 px and checks what a reader would see: every figure loads, the contents' links land on
their headings, nothing is wider than the window (at 390 px too), no table scrolls sideways, a header click
sorts its table (every kind of cell by its number), the console stays clean. Skipped where no Chromium is
installed, unless ``JAXAPF_REQUIRE_BROWSER=1`` (``.ci/run``)."""

from __future__ import annotations

import os
import shutil

import pytest
from test_report import RESAMPLES, make_rows, write_sweep

from jaxapf.cli import main

pytestmark = pytest.mark.slow

CHROMIUM = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    required = os.environ.get("JAXAPF_REQUIRE_BROWSER") == "1"
    if CHROMIUM is None:
        if required:
            pytest.fail("JAXAPF_REQUIRE_BROWSER=1 but no chromium on PATH")
        pytest.skip("no chromium on PATH (apt-get install chromium)")
    try:
        from playwright import sync_api
    except ImportError:
        if required:
            pytest.fail("JAXAPF_REQUIRE_BROWSER=1 but playwright is not installed (pip install -e '.[test]')")
        pytest.skip("playwright is not installed")
    tmp = tmp_path_factory.mktemp("browser")
    out = tmp / "report"
    assert main(["report", str(write_sweep(tmp / "s.parquet", make_rows())), "--out", str(out),
                 "--resamples", str(RESAMPLES), "--gallery", "0"]) == 0
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        tab = browser.new_page(viewport={"width": 1280, "height": 900})
        messages = []
        tab.on("console", lambda m: messages.append((m.type, m.text)))
        tab.on("pageerror", lambda e: messages.append(("pageerror", str(e))))
        tab.goto((out / "report.html").as_uri())
        tab.wait_for_load_state("load")
        yield tab, messages
        browser.close()


def test_every_figure_loads(page):
    tab, _ = page
    sizes = tab.eval_on_selector_all("img", "imgs => imgs.map(i => [i.complete, i.naturalWidth])")
    assert len(sizes) >= 5 and all(done and width > 0 for done, width in sizes)


def test_the_contents_links_land_on_their_headings(page):
    tab, _ = page
    links = tab.eval_on_selector_all("nav.contents a", "as => as.map(a => a.getAttribute('href'))")
    assert len(links) >= 8
    for href in links:
        tab.click(f"nav.contents a[href='{href}']")
        assert tab.evaluate("location.hash") == href
        top = tab.evaluate(f"document.getElementById('{href[1:]}').getBoundingClientRect().top")
        bottom = tab.evaluate("window.scrollY + window.innerHeight >= document.documentElement.scrollHeight - 1")
        assert abs(top) < 2 or (bottom and 0 < top < 900)  # at the heading, or as far as the page goes


def test_nothing_is_wider_than_the_window(page):
    tab, _ = page
    assert tab.evaluate("document.documentElement.scrollWidth") <= 1280
    wide = tab.evaluate("""Array.from(document.querySelectorAll('body *')).filter(e => {
        const r = e.getBoundingClientRect(); return r.right > 1280.5 && !e.closest('table');}).length""")
    assert wide == 0  # tables scroll inside themselves; nothing else reaches past the window


def test_no_table_scrolls_sideways_at_1280_px(page):
    """Long labels wrap: every table fits the page's column, the verdict matrix too."""
    tab, _ = page
    wide = tab.evaluate("""Array.from(document.querySelectorAll('table')).filter(t => t.scrollWidth > t.clientWidth + 1)
        .map(t => [t.scrollWidth, t.clientWidth, t.rows[0].textContent.slice(0, 60)])""")
    assert wide == []


def test_nothing_is_wider_than_a_phone_at_390_px(page):
    """At 390 px no element reaches past the window; a table too wide for it scrolls inside its own box."""
    tab, _ = page
    tab.set_viewport_size({"width": 390, "height": 800})
    try:
        wide = tab.evaluate("""Array.from(document.querySelectorAll('body *')).filter(e => {
            const r = e.getBoundingClientRect(); return r.right > 390.5 && !e.closest('table');})
            .map(e => e.tagName + ':' + (e.textContent || '').slice(0, 40))""")
        page_width = tab.evaluate("document.documentElement.scrollWidth")
    finally:
        tab.set_viewport_size({"width": 1280, "height": 900})
    assert wide == [] and page_width <= 390


def test_a_header_click_sorts_its_table(page):
    tab, _ = page
    table = "table.sortable >> nth=3"  # a table of numbers with intervals
    first = [float(v.split()[0]) for v in tab.locator(table).locator("tbody tr td:nth-child(3)").all_inner_texts()]
    tab.locator(table).locator("th:nth-child(3)").click()
    up = [float(v.split()[0]) for v in tab.locator(table).locator("tbody tr td:nth-child(3)").all_inner_texts()]
    assert up == sorted(first)
    tab.locator(table).locator("th:nth-child(3)").click()
    assert [float(v.split()[0]) for v in tab.locator(table).locator("tbody tr td:nth-child(3)").all_inner_texts()] \
        == sorted(first, reverse=True)


def test_the_console_stays_clean(page):
    tab, messages = page
    assert not [m for m in messages if m[0] in ("error", "pageerror", "warning")]


#: One cell of each kind a report's tables hold, in the order a header click puts them.
SORTED_CELLS = ["−∞", "−3.5 [−4.1, −2.9]", "[−0.917, +0.917]", "+0 [−0.917, +0.917]", "<0.001 *", "0.001",
                "0.011 *", "0.5 %", "1.000", "12 / 512", "99.8 %", "1,234", "4,096 (80 %)", ">1e4", "+∞",
                "n/a", "trap"]


def test_every_kind_of_cell_sorts_by_its_number(page):
    """p-values with '<', intervals, percentages, counts with thousands separators, infinities, text last."""
    tab, _ = page
    cells = list(reversed(SORTED_CELLS))
    order = tab.evaluate("""cells => cells.map(c => [c, sortKey(c)]).sort((a, b) => {const x = a[1], y = b[1];
        return typeof x === typeof y ? (x < y ? -1 : x > y ? 1 : 0) : (typeof x === 'number' ? -1 : 1);})
        .map(p => p[0])""", cells)
    assert order == SORTED_CELLS
