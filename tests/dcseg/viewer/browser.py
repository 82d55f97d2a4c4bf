"""Headless Chromium for the viewer tests: Debian's ``chromium`` driven by Playwright.

No browser is ever downloaded: the executable is ``$DCSEG_CHROMIUM`` or ``chromium`` on the
PATH (``apt-get install chromium``; ``scripts/test.sh`` installs it when run as root).
WebGL2 runs on the CPU through SwiftShader.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray
from playwright.sync_api import Browser, Page, sync_playwright

from dcseg.viewer import ViewerNotBuilt, bundle

CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
VIEWPORT = {"width": 800, "height": 560}


def chromium_path() -> str | None:
    """The Chromium executable to drive, or None when none is installed."""
    configured = os.environ.get("DCSEG_CHROMIUM")
    if configured:
        return configured if os.access(configured, os.X_OK) else None
    return shutil.which("chromium") or shutil.which("chromium-browser")


@contextmanager
def launch(executable: str) -> Iterator[Browser]:
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    """Headless Chromium for one test module (Playwright's sync API runs one at a time);
    skipped where none is installed, failed where the viewer bundle is
    missing (a build step that can always run)."""
    executable = chromium_path()
    if executable is None:
        pytest.skip(
            "no Chromium to drive: install Debian's chromium package (apt-get install -y "
            "chromium; scripts/test.sh does as root) or set DCSEG_CHROMIUM"
        )
    require_bundle()
    with launch(executable) as chromium:
        yield chromium


def require_bundle() -> None:
    """Fail (not skip) when the viewer bundle is missing: building it can always run."""
    try:
        bundle()
    except ViewerNotBuilt as error:
        pytest.fail(str(error))


@pytest.fixture(scope="module")
def built() -> None:
    """The viewer bundle is built (else the test fails naming the build step)."""
    require_bundle()


def open_viewer(browser: Browser, url: str) -> Page:
    """A new page at ``url`` whose viewer has loaded (raises with the page's error if not)."""
    page = browser.new_page(viewport=VIEWPORT)  # type: ignore[arg-type]
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(url)
    wait_loaded(page, errors)
    return page


def wait_loaded(page: Page, errors: list[str] | None = None) -> None:
    """Wait until the viewer has loaded its data; fails with the page's error message."""
    hook = "window.dcsegViewer && (window.dcsegViewer.loaded || window.dcsegViewer.error)"
    page.wait_for_function(f"() => {hook}", timeout=60_000)
    if not page.evaluate("() => window.dcsegViewer.loaded"):
        shown = page.locator("#error").text_content()
        raise AssertionError(f"viewer did not load: {shown!r}, page errors {errors}")


def viewer_call(page: Page, expression: str, arg: Any = None) -> Any:
    """Evaluate ``expression`` (a function of the viewer and ``arg``) in the page."""
    return page.evaluate(
        f"([arg]) => window.dcsegViewer.ready.then((viewer) => ({expression})(viewer, arg))", [arg]
    )


def screenshot(page: Page) -> NDArray[np.int16]:
    """The canvas as ``[H, W, 3]`` int16 RGB."""
    # a page screenshot clipped to the canvas: an element screenshot first waits for the
    # element to be "stable" over animation frames, which a busy software renderer delays
    box = page.locator("#canvas").bounding_box()
    assert box is not None, "the canvas is not displayed"
    png = page.screenshot(clip=box)
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None, "the canvas screenshot is not a readable PNG"
    rgb: NDArray[np.int16] = image[:, :, ::-1].astype(np.int16)
    return rgb


def settled(page: Page, timeout: float = 30.0) -> NDArray[np.int16]:
    """A screenshot once two consecutive ones (0.3 s apart) are equal: Spark sorts the splats
    in a worker, so a change shows after a few frames."""
    previous = screenshot(page)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        time.sleep(0.3)
        current = screenshot(page)
        if np.array_equal(current, previous):
            return current
        previous = current
    raise AssertionError(f"the canvas kept changing for {timeout} s")
