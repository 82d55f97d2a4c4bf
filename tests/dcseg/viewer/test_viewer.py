"""The browser viewer in headless Chromium: loading, picking, hide/show, colours, download."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dcseg.io.exports import palette
from dcseg.io.ply import read_gaussians_ply, read_ply_extra
from dcseg.viewer.server import serving
from tests.dcseg.viewer.browser import open_viewer, settled, viewer_call
from tests.scenes.labelled import LabelledRun

BOX, BALL, FLOOR = 2, 3, 1


@pytest.fixture(scope="module")
def url(labelled_run: LabelledRun):
    with serving(labelled_run.folder) as address:
        yield address


@pytest.fixture
def page(browser, url):
    page = open_viewer(browser, url)
    yield page
    page.close()


def pixel_of(page, run: LabelledRun, instance_id: int) -> tuple[float, float]:
    """Viewport CSS pixel of the instance's centre of mass."""
    point = viewer_call(page, "(v, xyz) => v.project(xyz)", run.centre(instance_id))
    return point["x"], point["y"]


def selected(page) -> int | None:
    value: int | None = viewer_call(page, "(v) => v.view.selected")
    return value


def patch(image: np.ndarray, xy: tuple[float, float], radius: int = 10) -> np.ndarray:
    x, y = int(round(xy[0])), int(round(xy[1]))
    return image[y - radius : y + radius, x - radius : x + radius]


def test_loads_the_scene_and_lists_present_classes_and_objects(page, labelled_run):
    assert (
        page.locator("#status").text_content() == f"{len(labelled_run.means)} Gaussians, 3 objects"
    )
    objects = page.locator("#objects .row").all_text_contents()
    assert objects == ["#1 floor", "#2 box", "#3 ball"]
    classes = page.locator("#classes .row").all_text_contents()
    assert classes == ["none (0 objects)", "floor (1 object)", "box (1 object)", "ball (1 object)"]
    image = settled(page)
    assert image.std() > 10  # something was drawn, not a blank canvas


def test_click_on_projected_centre_selects_that_object(page, labelled_run):
    page.set_viewport_size({"width": 900, "height": 500})  # the camera follows the canvas
    page.wait_for_function(
        "() => { const v = window.dcsegViewer.viewer; const c = v.canvas; "
        "return c.clientHeight === 500 && v.camera.aspect === c.clientWidth / 500; }",
        timeout=5000,
    )
    for instance_id, label in ((BOX, "box"), (BALL, "ball")):
        page.mouse.click(*pixel_of(page, labelled_run, instance_id))
        assert selected(page) == instance_id
        assert page.locator('#selection dd[data-field="class"]').text_content() == label
        assert (
            page.locator('#selection dd[data-field="object"]').text_content() == f"#{instance_id}"
        )
    page.mouse.click(3, 3)  # background
    assert selected(page) is None


def test_hiding_an_object_changes_its_pixels_only(page, labelled_run):
    box, ball = pixel_of(page, labelled_run, BOX), pixel_of(page, labelled_run, BALL)
    before = settled(page)
    page.locator('#objects input[data-instance-id="2"]').uncheck()
    hidden = settled(page)
    assert np.abs(patch(hidden, box) - patch(before, box)).mean() > 40
    assert np.abs(patch(hidden, ball) - patch(before, ball)).mean() < 3
    page.mouse.click(*box)  # the box is hidden: the click reaches the floor below it
    assert selected(page) == FLOOR
    page.mouse.click(3, 3)
    page.locator('#objects input[data-instance-id="2"]').check()
    again = settled(page)
    assert np.abs(again - before).mean() < 1


def test_hiding_a_class_and_colouring_by_class(page, labelled_run):
    ball = pixel_of(page, labelled_run, BALL)
    by_instance = settled(page)
    assert np.abs(patch(by_instance, ball, 3).mean(axis=(0, 1)) - palette(3)[BALL - 1]).max() < 30
    page.locator('input[name="mode"][value="class"]').check()
    by_class = settled(page)
    assert np.abs(patch(by_class, ball, 3).mean(axis=(0, 1)) - palette(4)[3]).max() < 30
    page.locator('#classes input[data-class-id="3"]').uncheck()
    assert np.abs(patch(settled(page), ball) - patch(by_class, ball)).mean() > 40


def test_download_writes_the_selected_objects_gaussians(page, labelled_run, tmp_path):
    page.mouse.click(*pixel_of(page, labelled_run, BALL))
    with page.expect_download() as download:
        page.locator("#download").click()
    assert download.value.suggested_filename == "instance_3_ball.ply"
    path = tmp_path / "ball.ply"
    download.value.save_as(path)
    gaussians = read_gaussians_ply(path)
    members = labelled_run.instance_ids == BALL
    assert len(gaussians) == int(members.sum())
    assert np.array_equal(gaussians.means.numpy(), labelled_run.means[members])
    ids = read_ply_extra(path, "instance_id")
    assert ids is not None and set(ids.tolist()) == {BALL}


def test_a_broken_scene_file_is_reported_on_the_page(browser, tmp_path: Path, labelled_run):
    import shutil

    run = Path(shutil.copytree(labelled_run.folder, tmp_path / "run"))
    (run / "scene_labelled.ply").write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    with serving(run) as address:
        page = browser.new_page()
        page.goto(address)
        page.wait_for_function("() => window.dcsegViewer && window.dcsegViewer.error")
        message = page.locator("#error").text_content()
        page.close()
    assert (
        message
        == "run/scene_labelled.ply: only binary_little_endian PLY is supported (format ascii 1.0)"
    )
