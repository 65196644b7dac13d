"""Screenshots of ``sfb-video replay --web`` in headless Chromium, to look at the replay's layout.

Not a dependency of the package: it needs Debian's ``chromium`` (``apt-get install chromium``)
and Playwright in a separate environment (``python3 -m venv /tmp/shotenv && /tmp/shotenv/bin/pip
install playwright``; never ``playwright install``, which downloads its own browser). rerun's
viewer needs WebGL2, which SwiftShader gives a headless Chromium.

    sfb-video replay RUN --web &        # prints the URL once the viewer answers
    /tmp/shotenv/bin/python benchmarks/replay_screenshot.py URL OUT_PREFIX [name:x,y[;x,y] ...]

writes ``OUT_PREFIX_open.png`` once the viewer has drawn, then for each ``name`` clicks the
points in turn (the viewer draws on a canvas: there is no DOM to query) and writes
``OUT_PREFIX_name.png``. Clicks on the timeline menu did not take: for the frame and step
timelines, serve the copies ``benchmarks/replay_timelines.py`` writes.
"""

from __future__ import annotations

import sys
import tempfile
import time

from playwright.sync_api import sync_playwright

CHROMIUM = "/usr/bin/chromium"
FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    # Without these Chromium keeps calling out, and a closed network refuses it.
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-gl=angle",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]
DRAWN_S = 25.0
"""The viewer's wasm loads and draws well within this on two cores (it had drawn at 5 s)."""


def main(url: str, prefix: str, steps: list[str]) -> None:
    with sync_playwright() as playwright:
        context = playwright.chromium.launch_persistent_context(
            tempfile.mkdtemp(prefix="sfb-video-chromium-"),
            executable_path=CHROMIUM,
            headless=True,
            args=FLAGS,
            viewport={"width": 1600, "height": 1000},
        )
        page = context.new_page()
        page.goto(url)
        time.sleep(DRAWN_S)
        page.screenshot(path=f"{prefix}_open.png")
        for step in steps:
            name, clicks = step.split(":")
            for point in clicks.split(";"):
                x, y = (float(v) for v in point.split(","))
                # The viewer reads the pointer once a frame, and SwiftShader draws few frames a
                # second: a click whose press and release fall in one frame is lost.
                page.mouse.move(x, y)
                time.sleep(1)
                page.mouse.down()
                time.sleep(0.5)
                page.mouse.up()
                time.sleep(2)
            time.sleep(4)
            page.screenshot(path=f"{prefix}_{name}.png")
        context.close()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3:])
