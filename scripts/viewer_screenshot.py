"""Screenshot of the browser viewer on a run, for the docs (needs Chromium and the bundle).

    python scripts/viewer_screenshot.py runs/demo/run docs/viewer.png --hide-class wall

The README's picture: ``python scripts/viewer_screenshot.py runs/demo/run docs/viewer-demo.png
--mode class --hide-class wall --select 9 --size 1040x640``.

Serves RUN like ``dcseg view``, opens it in headless Chromium (tests/dcseg/viewer/browser.py),
hides the given classes, optionally selects an object (a click on its centroid) and writes the
page.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dcseg.viewer.server import serving  # noqa: E402
from tests.dcseg.viewer.browser import (  # noqa: E402
    chromium_path,
    launch,
    open_viewer,
    settled,
    viewer_call,
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--hide-class", action="append", default=[], help="class name to hide")
    parser.add_argument("--mode", choices=("instance", "class", "rgb"), default="instance")
    parser.add_argument("--select", type=int, help="click the centroid of this instance id")
    parser.add_argument("--size", default="1200x720", help="viewport WxH")
    args = parser.parse_args()
    executable = chromium_path()
    if executable is None:
        sys.stderr.write("no chromium: apt-get install -y chromium\n")
        return 1
    width, height = (int(v) for v in args.size.split("x"))
    with serving(args.run) as url, launch(executable) as browser:
        page = open_viewer(browser, url)
        page.set_viewport_size({"width": width, "height": height})
        page.locator(f'input[name="mode"][value="{args.mode}"]').check()
        for name in args.hide_class:
            rows = page.locator("#classes .row", has_text=f"{name} (")
            rows.locator("input").uncheck()
        if args.select is not None:
            records = json.loads((args.run / "instances.json").read_text())["instances"]
            centroid = next(r["centroid"] for r in records if r["id"] == args.select)
            xy = viewer_call(page, "(v, xyz) => v.project(xyz)", centroid)
            page.mouse.click(xy["x"], xy["y"])
        settled(page)
        png = page.screenshot()
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None, "the page screenshot is not a readable PNG"
    cv2.imwrite(str(args.out), image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    sys.stdout.write(f"{args.out}: {args.out.stat().st_size / 1024:.0f} KB\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
