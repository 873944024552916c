"""The 3D viewer page in a real headless Chromium (Debian's `chromium`, driven by Playwright): it loads without
console errors, draws a scene, the time slider moves the skeleton, playback follows the video, and a 1-minute clip
opens in under 2 s and draws faster than its frame rate. Skipped where chromium is not installed."""

from __future__ import annotations

import io
import shutil

import cv2
import numpy as np
import pytest

from physmocap.body.support import convex_hull_2d
from physmocap.io.video import VideoWriter
from physmocap.viz.viewer import distance_to_polygon, support_polygons, write_viewer
from test_export import synthetic_result

pytestmark = pytest.mark.slow  # a headless browser opens the viewer

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--no-first-run", "--autoplay-policy=no-user-gesture-required"]
RESOURCE_FAILURE = "Failed to load resource"


def write_test_video(path, frames: int, fps: float) -> None:
    """A small H.264 clip whose frames show their index."""
    with VideoWriter(path, fps, 96, 64, preset="ultrafast") as writer:
        for index in range(frames):
            image = np.full((64, 96, 3), 30, np.uint8)
            cv2.putText(image, str(index), (8, 44), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2)
            writer.write(image)


@pytest.fixture(scope="module")
def browser():
    if CHROMIUM is None:
        pytest.skip("chromium is not installed (apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("run")
    result = synthetic_result(frames=90)
    write_test_video(folder / "overlay.mp4", 90, float(result["fps"]))
    write_viewer(result, folder / "viewer.html")
    return folder


def open_page(browser, path):
    """A new page at `path`, its console errors and page errors collected, once the viewer is ready."""
    page = browser.new_page(viewport={"width": 1280, "height": 760})
    errors: list[str] = []
    page.on("console", lambda message: errors.append(message.text) if message.type == "error" else None)
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(path.as_uri())
    page.wait_for_function("window.physmocapViewer !== undefined")
    return page, errors


def canvas_image(page) -> np.ndarray:
    png = page.locator("#scene").screenshot()
    return cv2.imdecode(np.frombuffer(io.BytesIO(png).getvalue(), np.uint8), cv2.IMREAD_COLOR)


def test_loads_without_errors_and_draws_a_scene(browser, run_folder):
    page, errors = open_page(browser, run_folder / "viewer.html")
    page.wait_for_function("window.physmocapViewer.videoUsable")
    assert errors == []
    image = canvas_image(page)
    assert image.shape[0] > 100 and image.shape[1] > 100
    not_background = np.any(image < 235, axis=2).mean()
    assert not_background > 0.005  # grid, skeleton, ghost, forces
    coloured = np.abs(image.astype(int) - image.mean(axis=2, keepdims=True)).max(axis=2) > 60
    assert coloured.sum() > 200  # the blue and orange limbs, not only the grey grid
    page.close()


def test_time_slider_moves_the_skeleton(browser, run_folder):
    page, errors = open_page(browser, run_folder / "viewer.html")
    before_image = canvas_image(page)
    before = page.evaluate("window.physmocapViewer.screenPoint('pelvis')")
    page.locator("#time").fill("60")
    page.wait_for_function("window.physmocapViewer.frame === 60")
    page.evaluate("window.physmocapViewer.draw()")
    after = page.evaluate("window.physmocapViewer.screenPoint('pelvis')")
    assert np.hypot(after[0] - before[0], after[1] - before[1]) > 10  # 1.6 m of walking
    assert np.any(canvas_image(page) != before_image)
    assert page.locator("#clock").inner_text() == "2.00 s"
    video_time = page.evaluate("document.getElementById('video').currentTime")
    assert video_time == pytest.approx(60.5 / 30, abs=1e-3)
    assert errors == []
    page.close()


def test_playback_follows_the_video(browser, run_folder):
    page, errors = open_page(browser, run_folder / "viewer.html")
    page.wait_for_function("window.physmocapViewer.videoUsable")
    page.locator("#play").click()
    page.wait_for_function("window.physmocapViewer.frame >= 20", timeout=5000)
    state = page.evaluate("[window.physmocapViewer.frame, document.getElementById('video').currentTime]")
    assert abs(state[0] - state[1] * 30) <= 2  # the skeleton shows the video's frame
    page.locator("#play").click()
    assert not page.evaluate("window.physmocapViewer.playing")
    assert errors == []
    page.close()


def test_without_its_video_the_page_plays_on_its_own_clock(browser, tmp_path):
    write_viewer(synthetic_result(frames=30), tmp_path / "viewer.html")  # no overlay.mp4 beside it
    page, errors = open_page(browser, tmp_path / "viewer.html")
    page.wait_for_selector("#video-note", state="visible")
    assert "could not be played" in page.locator("#video-note").inner_text()
    page.locator("#play").click()
    page.wait_for_function("window.physmocapViewer.frame >= 10", timeout=5000)
    assert all(RESOURCE_FAILURE in e for e in errors)
    page.close()


def test_one_minute_clip_opens_in_under_2s_and_plays_at_its_frame_rate(browser, tmp_path):
    fps = 30.0
    frames = int(60 * fps)
    write_test_video(tmp_path / "overlay.mp4", frames, fps)
    write_viewer(synthetic_result(frames=frames, fps=fps), tmp_path / "viewer.html")
    page, errors = open_page(browser, tmp_path / "viewer.html")
    page.wait_for_function("window.physmocapViewer.videoUsable")
    timing = page.evaluate("""() => {
        const v = window.physmocapViewer;
        const begin = performance.now();
        for (let f = 0; f < v.frames; f += 10) v.setFrame(f);
        v.setFrame(0);
        return {ready: v.readyAt, decode: v.decodeMs, perFrame: (performance.now() - begin) / Math.ceil(v.frames / 10)};
    }""")
    assert timing["ready"] < 2000, timing  # ms from navigation start to the first frame drawn
    assert timing["perFrame"] < 1000 / fps, timing
    playback = page.evaluate("""async () => {
        const v = window.physmocapViewer, video = document.getElementById("video");
        v.play();
        await new Promise((resolve) => setTimeout(resolve, 300));
        const start = [performance.now(), v.drawCount, v.frame];
        await new Promise((resolve) => setTimeout(resolve, 2000));
        const seconds = (performance.now() - start[0]) / 1000;
        const result = {framesPerSecond: (v.frame - start[2]) / seconds,
                        drawsPerSecond: (v.drawCount - start[1]) / seconds,
                        lag: v.frame - Math.floor(video.currentTime * v.fps)};
        v.pause();
        return result;
    }""")
    assert playback["framesPerSecond"] == pytest.approx(fps, rel=0.15), playback
    assert playback["drawsPerSecond"] >= 0.9 * fps, playback  # every video frame gets drawn
    assert abs(playback["lag"]) <= 2, playback  # frames between the skeleton and the video
    assert errors == []
    print(f"1-minute clip: ready {timing['ready']:.0f} ms (decode {timing['decode']:.0f} ms), "
          f"{timing['perFrame']:.2f} ms per frame drawn; playback {playback}")
    page.close()


def test_support_polygon_geometry():
    square = np.array(convex_hull_2d(np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0], [0.5, 0.5]])))
    assert len(square) == 4 and np.cross(square[1] - square[0], square[2] - square[1]) > 0  # counter-clockwise
    assert distance_to_polygon(np.array([0.5, 0.5]), square) == 0.0
    assert distance_to_polygon(np.array([1.5, 0.5]), square) == pytest.approx(0.5)
    assert distance_to_polygon(np.array([0.5, 0.3]), np.array([[0.0, 0.0], [1.0, 0.0]])) == pytest.approx(0.3)
    points = np.zeros((2, 4, 3))
    points[:, :, 0] = [0.0, 0.2, 0.0, 0.2]
    points[:, :, 1] = [0.1, 0.1, -0.1, -0.1]
    vertices, counts = support_polygons(points, np.array([[True, True, True, True], [False] * 4]))
    np.testing.assert_array_equal(counts, [4, 0])
    assert distance_to_polygon(np.array([0.1, 0.0]), vertices[0, :4]) == 0.0
