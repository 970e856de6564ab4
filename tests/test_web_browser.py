"""The web page in a real headless browser: Debian's chromium driven by Playwright.

``shapeidx serve`` runs as a real process on a free port over a store built from real KiCad
parts; the test loads the page, uploads a part, sees that part at rank 1 with its thumbnail,
opens a hit's compare view, queries by clicking a thumbnail, browses the failed files, and
sees a bad upload reported on the page. It also pages through a 2,000-hit result sheet.

Skipped, with the reason, when chromium or Playwright is missing (``.ci/run`` installs
chromium; Playwright comes with the ``test`` extra and is never asked to download a browser).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
import urllib.request
from pathlib import Path

import pytest
from clitools import cli, shapeidx_command
from storetools import FAST_POINTS, small_kicad

CHROMIUM = os.environ.get("SHAPEIDX_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
if not Path(CHROMIUM).exists():
    pytest.skip(f"no chromium at {CHROMIUM} (apt-get install chromium; .ci/run does)", allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e '.[test]')")
pytest.importorskip("uvicorn", reason="the web extra is not installed (pip install -e '.[web]')")

CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def server(data_dir, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("browser")
    tree = small_kicad(data_dir, tmp, ("LED_SMD", "Diode_SMD", "Capacitor_Tantalum_SMD"))
    (tree / "broken").mkdir()
    (tree / "broken" / "truncated.wrl").write_text("#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ 0 0 0,")
    store = tmp / "s.shapeidx"
    result = cli("build", tree, "--store", store, "--points", FAST_POINTS)
    assert result.exit_code == 0, result.output
    port = free_port()
    log = open(tmp / "serve.log", "w")
    process = subprocess.Popen(shapeidx_command("serve", "--store", store, "--port", port), stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}/"
    deadline = time.monotonic() + 60
    while True:
        try:
            urllib.request.urlopen(url + "api/store", timeout=2).read()
            break
        except OSError:
            if process.poll() is not None or time.monotonic() > deadline:
                process.kill()
                pytest.fail(f"shapeidx serve did not start: {(tmp / 'serve.log').read_text()}")
            time.sleep(0.2)
    yield tree, url, tmp
    process.terminate()
    process.wait(timeout=20)
    log.close()


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    profile = tmp_path_factory.mktemp("chromium-profile")
    with sync_api.sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            str(profile), executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True, viewport={"width": 1280, "height": 1000}
        )
        yield context
        context.close()


def loaded(page, selector):
    """True when every image under ``selector`` has loaded (a real picture, not a broken icon)."""
    return page.eval_on_selector_all(selector, "imgs => imgs.length > 0 && imgs.every(i => i.complete && i.naturalWidth > 0)")


def test_upload_query_compare_and_browse(server, browser):
    tree, url, tmp = server
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.wait_for_selector("#store-info:has-text('30 parts')")

    part = sorted((tree / "Diode_SMD").iterdir())[4]
    page.set_input_files("#file", str(part))
    page.fill("#top", "6")
    page.click("#upload-button")
    page.wait_for_selector("[data-testid=hit]")
    hits = page.locator("[data-testid=hit]")
    assert hits.count() == 6
    first = hits.nth(0)
    assert first.get_attribute("data-rank") == "1" and first.get_attribute("data-id") == f"Diode_SMD/{part.name}"
    assert "identical signature" in first.inner_text()
    page.wait_for_function("() => [...document.querySelectorAll('[data-testid=hit] img')].every(i => i.complete)")
    assert loaded(page, "[data-testid=hit] img") and loaded(page, "[data-testid=query-card] img")
    page.screenshot(path=str(tmp / "query.png"))

    # a hit's compare view: both thumbnails, the overlaid histograms, the distances
    second = hits.nth(1)
    distance = second.locator(".distance").inner_text().split()[-1]
    second_id = second.get_attribute("data-id")
    second.locator("[data-testid=compare]").click()
    view = page.wait_for_selector("[data-testid=compare-view]")
    page.wait_for_function("() => [...document.querySelectorAll('[data-testid=compare-view] img')].every(i => i.complete)")
    assert loaded(page, "[data-testid=compare-view] img") and page.locator("[data-testid=compare-view] img").count() == 2
    assert page.locator("[data-testid=compare-view] polyline").count() == 8  # 4 histograms x 2 parts
    assert second_id in view.inner_text()
    weighted = page.locator("[data-testid=distances] tr:has-text('Weighted') td").nth(1).inner_text()
    assert float(weighted) == pytest.approx(float(distance), rel=1e-3)

    # click any thumbnail to query by it
    page.go_back()
    page.wait_for_selector("[data-testid=hit]")
    page.locator(f"[data-testid=hit][data-id='{second_id}'] img").click()
    page.wait_for_selector(f"[data-testid=query-card]:has-text('{second_id}')")
    assert page.locator("[data-testid=hit]").first.get_attribute("data-id") == second_id

    # another metric re-queries
    page.select_option("#metric", "all")
    page.wait_for_function("() => location.hash.includes('metric=all')")
    page.wait_for_selector("[data-testid=query-card]:has-text('ALL (plain D2)')")

    # browse: the failed file and its reason
    page.click("#browse-link")
    page.wait_for_selector("[data-testid=entries]")
    page.select_option("#status-filter", "failed")
    row = page.wait_for_selector("tr[data-status=failed]")
    assert "broken/truncated.wrl" in row.inner_text() and row.query_selector("td.reason").inner_text()
    assert not errors, errors


def test_every_metric_of_the_menu_answers_and_the_where_filter_narrows(server, browser):
    """The distance menu is the registry's (labels and all); each metric answers (the angle
    metrics were a 422 before); a where condition keeps only the matching parts, and one that
    matches nothing says so on the page."""
    from shapeidx.distance.metrics import REGISTRY

    tree, url, tmp = server
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    entry = "LED_SMD/" + sorted(p.name for p in (tree / "LED_SMD").iterdir())[1]
    page.goto(url + "#/query?id=" + entry)
    page.wait_for_selector("[data-testid=hit]")
    options = page.eval_on_selector_all("#metric option", "os => os.map(o => [o.value, o.textContent])")
    assert options == [[m.name, m.label] for m in REGISTRY.values()]
    for name, label in options:
        page.select_option("#metric", name)
        page.wait_for_function(f"() => location.hash.includes('metric={name}')")
        page.wait_for_selector(f"[data-testid=query-card]:has-text('{label},')")
        assert page.locator("[data-testid=hit]").first.get_attribute("data-id") == entry, name
        assert page.locator("[data-testid=error]").is_hidden(), (name, page.locator("[data-testid=error]").inner_text())
    page.fill("#where", "path~Diode_SMD/*")
    page.dispatch_event("#where", "change")
    page.wait_for_function("() => location.hash.includes('where=')")
    page.wait_for_selector("[data-testid=query-card]:has-text('parts left')")
    ids = [h.get_attribute("data-id") for h in page.locator("[data-testid=hit]").all()]
    assert ids and all(i.startswith("Diode_SMD/") for i in ids)
    page.fill("#where", "path~nothing/*")
    page.dispatch_event("#where", "change")
    page.wait_for_selector("[data-testid=no-answer]")
    assert "no entry of the store matches" in page.locator("[data-testid=no-answer]").inner_text()
    assert page.locator("[data-testid=hit]").count() == 0
    page.screenshot(path=str(tmp / "where.png"))
    assert not errors, errors


def test_the_same_part_box_orders_by_the_exact_measures(server, browser):
    """Ticking *Same part* asks the same-part order (``same_part=1``, kept in the address): the
    page says so, every hit shows its gap, the part itself first at gap 0; a hit clicked keeps
    the order; unticked, the gaps are gone."""
    tree, url, tmp = server
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    entry = "Capacitor_Tantalum_SMD/" + sorted(p.name for p in (tree / "Capacitor_Tantalum_SMD").iterdir())[2]
    page.goto(url + "#/query?id=" + entry)
    page.wait_for_selector("[data-testid=hit]")
    assert page.locator("[data-testid=shape-gap]").count() == 0
    page.check("#same-part")
    page.wait_for_function("() => location.hash.includes('same_part=1')")
    page.wait_for_selector("[data-testid=query-card]:has-text('same-part order')")
    hits = page.locator("[data-testid=hit]")
    assert hits.first.get_attribute("data-id") == entry
    assert page.locator("[data-testid=shape-gap]").count() == hits.count() > 1
    assert page.locator("[data-testid=shape-gap]").first.inner_text() == "gap 0"
    assert "left)" not in page.locator("[data-testid=query-card]").inner_text()  # an order, not a filter
    page.screenshot(path=str(tmp / "same-part.png"))
    second = hits.nth(1).get_attribute("data-id")
    hits.nth(1).locator("[data-testid=thumbnail]").click()
    page.wait_for_function(f"() => decodeURIComponent(location.hash).includes('id={second}')")
    assert "same_part=1" in page.evaluate("location.hash")
    page.wait_for_selector(f"[data-testid=hit][data-id='{second}'] [data-testid=shape-gap]")
    page.uncheck("#same-part")
    page.wait_for_function("() => !location.hash.includes('same_part')")
    page.wait_for_selector("[data-testid=query-card]:not(:has-text('same-part order'))")
    assert page.locator("[data-testid=shape-gap]").count() == 0
    assert not errors, errors


def test_a_bad_upload_is_a_message_on_the_page(server, browser, tmp_path):
    _, url, _ = server
    bad = tmp_path / "bracket.stl"
    bad.write_bytes(b"\x00\x01 not a part" * 20)
    page = browser.new_page()
    page.goto(url)
    page.wait_for_selector("#store-info:has-text('parts')")
    page.set_input_files("#file", str(bad))
    page.click("#upload-button")
    error = page.wait_for_selector("[data-testid=error]:visible")
    assert error.inner_text().startswith("bracket.stl: ")
    # the page still works afterwards
    page.goto(url + "#/browse")
    page.wait_for_selector("[data-testid=entries] tr[data-status=ok]")


def test_a_long_sheet_pages_in_the_browser(server, browser, tmp_path):
    """A 2,000-hit sheet opened from disk: 100 hits per page, the pager moves between them."""
    from shapeidx.pictures.sheet import PAGE, SheetHit, SheetPart, sheet_html
    from shapeidx.search import Searcher

    _, _, tmp = server
    with Searcher(tmp / "s.shapeidx") as searcher:
        signatures = [searcher.signature_at(i) for i in range(len(searcher))]
    hits = [SheetHit(SheetPart(f"part {k}", None, signatures[k % len(signatures)]), k + 1, 0.001 * k) for k in range(2000)]
    sheet = tmp_path / "long.html"
    sheet.write_text(sheet_html("long", SheetPart("q", None, signatures[0]), hits, []))
    page = browser.new_page()
    page.goto(sheet.as_uri())
    assert page.locator("article.hit:visible").count() == PAGE
    page.click("nav.pages button:has-text('101-200')")
    visible = page.locator("article.hit:visible")
    assert visible.count() == PAGE and visible.first.get_attribute("data-rank") == "101"
