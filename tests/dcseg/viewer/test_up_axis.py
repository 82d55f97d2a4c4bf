"""The viewer's up axis comes from the run's ``frame.json`` (derived from the run's poses as the
exports derive it); the panel's choice overrides it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import Browser, Page

from dcseg.viewer.server import serving
from tests.dcseg.viewer.browser import open_viewer, viewer_call
from tests.dcseg.viewer.posed import Z_TO_Y, run_with_poses, tilt_about_x
from tests.scenes.labelled import LabelledRun


def camera_state(page: Page) -> dict[str, object]:
    """The camera's up vector, whether it came from frame.json, and the panel's choice."""
    state: dict[str, object] = viewer_call(
        page,
        "(v) => ({up: v.camera.up.toArray(), source: v.upSource, "
        "panel: document.getElementById('up').value, "
        "above: v.camera.position.clone().sub(v.controls.target).dot(v.camera.up)})",
    )
    return state


def view(browser: Browser, run: Path) -> dict[str, object]:
    with serving(run) as url:
        page = open_viewer(browser, url)
        try:
            return camera_state(page)
        finally:
            page.close()


def test_a_y_up_run_is_shown_with_y_up_and_the_panel_overrides_it(
    browser: Browser, labelled_run: LabelledRun, tmp_path: Path
):
    run = run_with_poses(labelled_run, tmp_path / "run", Z_TO_Y)
    with serving(run) as url:
        page = open_viewer(browser, url)
        try:
            state = camera_state(page)
            assert (state["up"], state["source"], state["panel"]) == ([0, 1, 0], "frame.json", "+y")
            assert isinstance(state["above"], float) and state["above"] > 0  # looks down on it
            page.locator("#up").select_option("+x")
            assert camera_state(page)["up"] == [1, 0, 0]
        finally:
            page.close()


def test_a_z_up_run_is_shown_with_z_up(browser, labelled_run, tmp_path):
    state = view(browser, run_with_poses(labelled_run, tmp_path / "run", np.eye(4)))
    assert (state["up"], state["source"], state["panel"]) == ([0, 0, 1], "frame.json", "+z")


def test_an_up_estimate_off_the_axes_is_used_as_it_is(browser, labelled_run, tmp_path):
    run = run_with_poses(labelled_run, tmp_path / "run", tilt_about_x(30))
    state = view(browser, run)
    assert (state["source"], state["panel"]) == ("frame.json", "run")
    expected = [0.0, -math.sin(math.radians(30)), math.cos(math.radians(30))]
    assert state["up"] == pytest.approx(expected, abs=1e-5)


def test_a_run_without_poses_falls_back_to_z_up(browser, labelled_run):
    state = view(browser, labelled_run.folder)
    assert (state["up"], state["source"], state["panel"]) == ([0, 0, 1], "default", "+z")
