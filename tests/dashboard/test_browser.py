"""The printed URL in a real browser: headless Chromium draws the live swarm map.

Needs Debian's `chromium` (apt-get install chromium); skipped without it. The page is 1024x576:
on a software rasteriser each frame costs time in proportion to its pixels. The last screenshot
is kept in the test's temporary directory; with DASHBOARD_SCREENSHOT=PATH set, a 1600x900 one
taken some seconds later (trails and plots filled in) is also written to PATH, e.g.
docs/dashboard.png.
"""

from __future__ import annotations

import io
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from services.dashboard.scene import ROBOT_COLOURS
from tests.dashboard.browser import HeadlessChromium, find_chromium, save
from tests.dashboard.conftest import Child, free_port, start_dashboard, start_swarm

pytestmark = pytest.mark.slow

CHROMIUM = find_chromium()
SCREENSHOT_ENV = "DASHBOARD_SCREENSHOT"
MAP_WIDTH_FRACTION = 0.55
"""The map is the left part of the default layout."""
COLOUR_TOLERANCE = 24
MIN_PIXELS_PER_ROBOT = 100
"""A body disc at 1024x576 shows about 300 pixels of its robot's colour."""
PAGE_SIZE_PX = (1024, 576)
DOCS_SIZE_PX = (1600, 900)
DRAW_TIMEOUT_S = 100.0
"""The viewer is 43 MB of wasm rendered on a software rasteriser: on a busy 2-core machine it
can take a minute to start."""


def robot_pixels(png: bytes, robots: int = 3) -> list[int]:
    """Per robot, how many pixels of the map area have (nearly) its colour."""
    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)
    map_area = image[:, : int(image.shape[1] * MAP_WIDTH_FRACTION)]
    return [
        int(np.sum(np.max(np.abs(map_area - np.array(colour)), axis=-1) <= COLOUR_TOLERANCE))
        for colour in ROBOT_COLOURS[:robots]
    ]


@pytest.mark.skipif(
    CHROMIUM is None,
    reason="needs Chromium to render the Rerun web viewer headless: apt-get install chromium",
)
def test_web_viewer_draws_the_live_swarm_map(tmp_path: Path, children: list[Child]) -> None:
    assert CHROMIUM is not None
    port = free_port()
    dashboard = start_dashboard("dashboard", tmp_path / "dashboard", port, tmp_path / "logs")
    children.append(dashboard.child)
    swarm = start_swarm(tmp_path / "swarm", port, "--duration", "300")
    children.append(swarm)
    swarm.wait_for_line("swarm lab:", timeout_s=60)

    counts: list[int] = []
    shot = tmp_path / "dashboard.png"
    with HeadlessChromium(CHROMIUM, *PAGE_SIZE_PX) as browser:
        browser.navigate(dashboard.url)
        deadline = time.monotonic() + DRAW_TIMEOUT_S
        while time.monotonic() < deadline:
            time.sleep(3.0)
            png = browser.screenshot_png(timeout_s=DRAW_TIMEOUT_S)
            save(png, shot)
            counts = robot_pixels(png)
            if min(counts) >= MIN_PIXELS_PER_ROBOT:
                break
        keep = os.environ.get(SCREENSHOT_ENV)
        if keep and min(counts) >= MIN_PIXELS_PER_ROBOT:
            browser.resize(*DOCS_SIZE_PX)
            time.sleep(15.0)
            save(browser.screenshot_png(timeout_s=DRAW_TIMEOUT_S), Path(keep))
    assert min(counts) >= MIN_PIXELS_PER_ROBOT, (
        f"the map did not draw the three robots within {DRAW_TIMEOUT_S} s: pixels of their "
        f"colours {counts}; last screenshot {shot}"
    )
    assert swarm.process.poll() is None, "the swarm ended before the browser looked"
    assert swarm.stop(signal.SIGINT) == 0
    assert dashboard.child.stop() == 0
