"""The HTML report in a real headless Chromium at 1280 px: no console error, no broken image,
no horizontal overflow, no network request; a full-page screenshot is saved.

Chromium is Debian's ``chromium`` package (``.ci/run`` installs it on CI; this test installs it
itself when it runs as root with apt-get), driven by the ``playwright`` package through
``executable_path``: playwright never downloads a browser of its own here.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

WIDTH = 1280


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    if os.geteuid() == 0 and shutil.which("apt-get"):
        env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "chromium"]):
            try:
                subprocess.run(cmd, env=env, capture_output=True, timeout=600, check=False)
            except (OSError, subprocess.TimeoutExpired):
                break
        path = shutil.which("chromium")
        if path:
            return path
    pytest.skip("Debian's chromium is not installed and cannot be installed here (apt-get)")


def test_report_in_headless_chromium(built_report: dict[str, Any], tmp_path: Path) -> None:
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="playwright (a dev extra) is not installed"
    )
    exe = _chromium()
    page_path = built_report["out"] / "report.html"
    requests: list[str] = []
    errors: list[str] = []
    shot = tmp_path / "report_1280.png"
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=exe, headless=True, args=["--no-sandbox", "--disable-gpu"]
        )
        try:
            page = browser.new_page(viewport={"width": WIDTH, "height": 900})
            page.on("request", lambda r: requests.append(r.url))
            page.on(
                "console",
                lambda m: (
                    errors.append(f"console {m.type}: {m.text}")
                    if m.type in ("error", "warning")
                    else None
                ),
            )
            page.on("pageerror", lambda e: errors.append(f"page error: {e}"))
            page.goto(page_path.as_uri(), wait_until="load")
            broken = page.evaluate(
                "[...document.images].filter(i => !(i.complete && i.naturalWidth > 0))"
                ".map(i => i.alt)"
            )
            n_images = page.evaluate("document.images.length")
            scroll_w = page.evaluate("document.documentElement.scrollWidth")
            too_wide = page.evaluate(
                f"[...document.querySelectorAll('body *')].filter(e => "
                f"e.getBoundingClientRect().right > {WIDTH} + 0.5).map(e => e.tagName)"
            )
            page.screenshot(path=str(shot), full_page=True)
        finally:
            browser.close()
    print(f"screenshot: {shot}")
    assert not errors, errors
    assert n_images >= 8 and not broken, f"broken images: {broken}"
    assert scroll_w <= WIDTH and not too_wide, f"horizontal overflow: {scroll_w} px, {too_wide}"
    external = [u for u in requests if u != page_path.as_uri() and not u.startswith("data:")]
    assert not external, f"network requests: {external}"
    assert shot.stat().st_size > 50_000
