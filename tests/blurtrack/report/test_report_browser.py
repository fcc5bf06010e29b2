"""The HTML report in a real headless Chromium at 1280 px: no console error, no broken image,
no horizontal overflow, no network request; a full-page screenshot is saved.

Chromium is Debian's ``chromium`` package (``.ci/run`` installs it on CI; this test installs it
itself when it runs as root with apt-get), driven by the ``playwright`` package through
``executable_path``: playwright never downloads a browser of its own here.
"""

from __future__ import annotations

import html.parser
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


#: Where Debian's package puts the browser; PATH is searched too.
CHROMIUM = "/usr/bin/chromium"


def _chromium_or_skip() -> str:
    path = CHROMIUM if os.access(CHROMIUM, os.X_OK) else shutil.which("chromium")
    if path is None:
        pytest.skip(f"chromium is not installed ({CHROMIUM} absent, none on PATH)")
    return path


def _headless(exe: str, *args: str) -> subprocess.CompletedProcess[str]:
    base = [exe, "--headless", "--disable-gpu", "--no-sandbox", "--hide-scrollbars"]
    return subprocess.run([*base, *args], capture_output=True, text=True, timeout=180, check=False)


class _Images(html.parser.HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.srcs: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "img":
            self.srcs.append(dict(attrs).get("src") or "")


def _decodes(data: bytes) -> bool:
    import cv2
    import numpy as np

    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) is not None


def test_report_screenshot_with_the_chromium_command(tmp_path: Path) -> None:
    """``blurtrack report`` on a small simulated session, rendered by the plain Chromium
    command (docs/report.md): the screenshot is a 1280x2000 PNG that is not blank, every
    ``<img>`` source resolves (inline ``data:`` or a file beside the page) to a decodable
    image, and in the browser no image is broken."""
    import base64
    import urllib.parse

    import cv2
    import numpy as np

    from blurtrack.cli import main
    from blurtrack.io import streaks as streak_table
    from blurtrack.io.calibration import write_calibration
    from blurtrack.io.session import load_session
    from blurtrack.testing.mini_session import write_synthetic_session

    exe = _chromium_or_skip()
    s = tmp_path / "S"
    write_synthetic_session(s, n_frames=6, resolution=(160, 120), grid=(5, 4), seed=3)
    session = load_session(s)
    streak_table.write(streak_table.from_truth(session.truth), s / "streaks.parquet")
    calib = tmp_path / "calib.yaml"
    write_calibration(session.initial_calibration(), calib)
    out = tmp_path / "report"
    assert (
        main(["report", str(s), "--calib", str(calib), "--out", str(out), "--overlays", "1"]) == 0
    )
    page = out / "report.html"

    # every <img> source resolves, inline or as a file beside the page
    parser = _Images()
    parser.feed(page.read_text(encoding="utf-8"))
    assert len(parser.srcs) >= 5
    for src in parser.srcs:
        if src.startswith("data:"):
            head, _, payload = src.partition(",")
            assert head.endswith(";base64") and _decodes(base64.b64decode(payload)), head
        else:
            target = out / urllib.parse.unquote(src)
            assert target.is_file() and _decodes(target.read_bytes()), src

    shot = tmp_path / "shot.png"
    r = _headless(exe, f"--screenshot={shot}", "--window-size=1280,2000", page.as_uri())
    assert shot.is_file(), r.stderr[-2000:]
    img = cv2.imread(str(shot), cv2.IMREAD_GRAYSCALE)
    assert img is not None and img.shape == (2000, 1280)
    ink = float(np.mean(img < 200))  # text, tables, figures on a white page
    assert img.std() > 10 and 0.01 < ink < 0.9, (img.std(), ink)

    # in the browser itself: no image that failed to load or decode
    probe = out / "probe.html"
    script = (
        "<script>window.addEventListener('load',()=>{const b=[...document.images].filter("
        "i=>!(i.complete&&i.naturalWidth>0)).length;document.body.dataset.broken=b;"
        "document.body.dataset.images=document.images.length;});</script></body>"
    )
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", script))
    r = _headless(exe, "--virtual-time-budget=10000", "--dump-dom", probe.as_uri())
    assert f'data-images="{len(parser.srcs)}"' in r.stdout, r.stdout[-500:]
    assert 'data-broken="0"' in r.stdout, r.stdout[-500:]
    # negative control: the same probe sees a missing image
    broken = out / "broken.html"
    broken.write_text(f"<html><body><img src='missing.png' alt='x'>{script}</html>")
    r = _headless(exe, "--virtual-time-budget=10000", "--dump-dom", broken.as_uri())
    assert 'data-broken="1"' in r.stdout, r.stdout[-500:]
