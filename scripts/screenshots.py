#!/usr/bin/env python3
"""The screenshots of docs/: a result sheet and the web page, taken in headless chromium.

    python scripts/screenshots.py --store kicad6.shapeidx [--out docs/images]

``--store`` is a store of the kicad6 folder (``shapeidx build ../shared/data/kicad6 --store
kicad6.shapeidx``). Writes ``sheet.png`` (``shapeidx query BatteryHolder_Keystone_500.wrl --sheet``),
``serve-query.png`` (the page after uploading that part) and ``serve-compare.png`` (the
compare view of its third hit). Needs Debian's chromium and the test extra (Playwright).
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

from playwright.sync_api import sync_playwright

from shapeidx.pictures.sheet import answer_sheet
from shapeidx.search import Searcher

REPO = Path(__file__).resolve().parents[1]
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
QUERY = "Battery/BatteryHolder_Keystone_500.wrl"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def all_images_loaded(page) -> None:
    page.wait_for_function("() => [...document.images].every(i => i.complete && i.naturalWidth > 0)", timeout=120_000)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--store", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "images")
    parser.add_argument("--chromium", default="/usr/bin/chromium")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with Searcher(args.store) as searcher:
        part = Path(searcher.root) / QUERY
    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as p:
        browser = p.chromium.launch_persistent_context(Path(tmp) / "profile", executable_path=args.chromium, args=ARGS,
                                                       headless=True, viewport={"width": 1280, "height": 1000})
        sheet = Path(tmp) / "sheet.html"
        with Searcher(args.store) as searcher:  # the command line's road: shapeidx query PART --sheet
            question = searcher.query_of_part(part, threads=2)
            answer_sheet(searcher, searcher.search(question, 12, "weighted"), question, sheet)
        page = browser.new_page()
        page.goto(sheet.as_uri())
        all_images_loaded(page)
        page.screenshot(path=str(args.out / "sheet.png"))

        port = free_port()
        server = subprocess.Popen([sys.executable, "-m", "shapeidx.cli", "serve", "--store", str(args.store), "--port", str(port)])
        try:
            url = f"http://127.0.0.1:{port}/"
            for _ in range(600):
                try:
                    urllib.request.urlopen(url + "api/store", timeout=2)
                    break
                except OSError:
                    time.sleep(0.2)
            page = browser.new_page()
            page.goto(url)
            page.wait_for_selector("#store-info:has-text('parts')")
            page.set_input_files("#file", str(part))
            page.click("#upload-button")
            page.wait_for_selector("[data-testid=hit]")
            all_images_loaded(page)
            page.screenshot(path=str(args.out / "serve-query.png"))
            page.locator("[data-testid=hit][data-rank='3'] [data-testid=compare]").click()
            page.wait_for_selector("[data-testid=compare-view]")
            all_images_loaded(page)
            page.screenshot(path=str(args.out / "serve-compare.png"))
        finally:
            server.terminate()
            server.wait(timeout=30)
        browser.close()
    for name in ("sheet.png", "serve-query.png", "serve-compare.png"):
        print(f"wrote {args.out / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
