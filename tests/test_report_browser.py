"""The report opened in a real headless Chromium (Debian's `chromium`, driven by Playwright, no
browser download): no console errors, every request file:/data:/blob:, every image decodes, the
video reaches a playable state, and a screenshot is written.

`make test` installs chromium (apt, `make browser`) and playwright (the test extra); this test
fails (never skips) when they are missing.
"""
from __future__ import annotations

import os
from pathlib import Path

from _export_store import optimised_report

CHROMIUM = os.environ.get("VFCLI_CHROMIUM", "/usr/bin/chromium")


def test_report_in_headless_chromium(tmp_path_factory):
    from playwright.sync_api import sync_playwright

    assert Path(CHROMIUM).exists(), f"{CHROMIUM} missing: run `make browser` (apt-get install chromium)"
    # the page `vfcli report` writes of the shared optimised store, made once for tests/test_report.py too
    html = optimised_report(tmp_path_factory)
    d = tmp_path_factory.mktemp("browser")
    shot_dir = Path(os.environ.get("VFCLI_SCREENSHOT_DIR", d))
    shot_dir.mkdir(parents=True, exist_ok=True)
    errors, requests = [], []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox", "--disable-gpu"])
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 900})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("request", lambda r: requests.append(r.url))
            page.on("requestfailed", lambda r: errors.append(f"request failed: {r.url[:80]}"))
            page.goto(html.as_uri(), wait_until="load")
            decoded = page.evaluate("""async () => Promise.all(Array.from(document.images).map(
                img => img.decode().then(() => img.naturalWidth > 0 && img.naturalHeight > 0, () => false)))""")
            page.wait_for_function("() => { const v = document.querySelector('video');"
                                   " return v && (v.readyState >= 3 || v.error); }", timeout=30000)
            video = page.evaluate("() => { const v = document.querySelector('video'); return {ready: v.readyState,"
                                  " error: v.error && v.error.message, w: v.videoWidth, h: v.videoHeight,"
                                  " duration: v.duration}; }")
            played = page.evaluate("""async () => { const v = document.querySelector('video');
                await v.play(); await new Promise(r => setTimeout(r, 400)); return v.currentTime; }""")
            shot = shot_dir / "report_screenshot.png"
            page.screenshot(path=str(shot), full_page=False)
            full = shot_dir / "report_full.png"
            page.screenshot(path=str(full), full_page=True)
        finally:
            browser.close()
    assert errors == []
    bad = [u[:80] for u in requests if not u.startswith(("file:", "data:", "blob:"))]
    assert bad == []
    assert len(decoded) >= 10 and all(decoded), decoded
    assert video["error"] is None and video["ready"] >= 3 and video["w"] > 100 and video["duration"] > 0, video
    assert played > 0
    assert shot.stat().st_size > 10_000
