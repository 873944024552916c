"""Overlay video and result figure on a small synthetic video."""

from __future__ import annotations

import threading
import time
from fractions import Fraction

import av
import cv2
import numpy as np
import pytest

from physmocap.body.kinematics import forward_kinematics
from physmocap.body.model import CONTACT_POINTS, JOINT_NAMES, build_body_model, template_lengths
from physmocap.io.video import VideoWriter, yuv420_planes
from physmocap.viz.figures import result_figure
from physmocap.viz.overlay import (
    BANNER_COLOUR,
    YuvScratch,
    _banner_box,
    _banner_layout,
    _banners,
    _draw_in_place,
    _draw_yuv420,
    _drawn_box,
    render_overlay,
    skeleton_edges,
    start_overlay,
)

WIDTH, HEIGHT, FRAMES, FPS = 320, 240, 10, 25.0
BACKGROUND = 60  # grey level of the synthetic frames


@pytest.fixture(scope="module")
def body():
    return build_body_model(template_lengths(1.7), 70)


@pytest.fixture(scope="module")
def scene(body):
    """The rest pose seen from the front (+x) by an orthographic camera: (P, 3) world points, (P, 2) pixels."""
    world = forward_kinematics(body, body.rest_qpos).points[0]
    pixels_per_metre = 120.0
    pixels = np.stack([WIDTH / 2 - pixels_per_metre * world[:, 1], HEIGHT - 15 - pixels_per_metre * world[:, 2]],
                      axis=1)
    return world, pixels


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    path = tmp_path_factory.mktemp("video") / "input.mp4"
    with VideoWriter(path, FPS, WIDTH, HEIGHT) as writer:
        for _ in range(FRAMES):
            writer.write(np.full((HEIGHT, WIDTH, 3), BACKGROUND, np.uint8))
    return path


def decode(path) -> tuple[str, list[np.ndarray]]:
    """Codec name and the BGR frames of a video, decoded with PyAV."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        codec = stream.codec_context.name
        frames = [frame.to_ndarray(format="bgr24") for frame in container.decode(stream)]
    return codec, frames


def pixel(frame: np.ndarray, point: np.ndarray) -> np.ndarray:
    return frame[int(round(point[1])), int(round(point[0]))].astype(int)


def test_skeleton_edges_connect_every_named_point(body):
    edges = skeleton_edges(body)
    connected = {body.point_names[i] for edge in edges for i in edge}
    assert connected == set(body.point_names)
    assert set(JOINT_NAMES) <= connected
    # One tree-like component: walking the edges from the pelvis reaches every point.
    reached, frontier = {0}, [0]
    while frontier:
        node = frontier.pop()
        for i, j in edges:
            for a, b in ((i, j), (j, i)):
                if a == node and b not in reached:
                    reached.add(b)
                    frontier.append(b)
    assert reached == set(range(len(body.point_names)))


def test_overlay_video_is_h264_with_the_skeleton_drawn(body, scene, video, tmp_path):
    _, pixels = scene
    points_2d = np.tile(pixels, (FRAMES, 1, 1))
    valid = np.ones(FRAMES, bool)
    valid[3] = False
    keypoints = np.zeros((FRAMES, 33, 3))
    keypoints[:, 0] = [40.0, 40.0, 0.9]  # one confident detection in a corner
    contacts = np.zeros((FRAMES, 4), bool)
    contacts[:5] = True
    done: list[int] = []
    out = tmp_path / "overlay.mp4"
    render_overlay(video, out, points_2d, skeleton_edges(body), valid, keypoints=keypoints, contacts=contacts,
                   labels=body.point_names, progress=lambda n, total: done.append(n))

    codec, frames = decode(out)
    assert codec == "h264"
    assert b"rc=cqp" in out.read_bytes()  # a constant quantiser: no rate control's analysis per frame
    assert len(frames) == FRAMES and frames[0].shape == (HEIGHT, WIDTH, 3)
    assert done == list(range(1, FRAMES + 1))
    index = {name: i for i, name in enumerate(body.point_names)}
    spine_middle = (pixels[index["pelvis"]] + pixels[index["neck"]]) / 2
    left_shin_middle = (pixels[index["left_knee"]] + pixels[index["left_ankle"]]) / 2
    right_shin_middle = (pixels[index["right_knee"]] + pixels[index["right_ankle"]]) / 2
    frame = frames[0]
    assert pixel(frame, spine_middle).min() > BACKGROUND + 100  # white centre line
    blue, _, red = pixel(frame, left_shin_middle)
    assert blue > red + 60  # left side blue-ish
    blue, _, red = pixel(frame, right_shin_middle)
    assert red > blue + 60  # right side orange-ish
    assert pixel(frame, np.array([40.0, 40.0])).max() > BACKGROUND + 80  # detector keypoint
    # The invalid frame has the banner at the top and no skeleton.
    banner = frames[3][2:6, :, :].reshape(-1, 3).mean(axis=0)
    assert np.abs(banner - np.array(BANNER_COLOUR)).max() < 40
    assert np.abs(pixel(frames[3], spine_middle) - BACKGROUND).max() < 15


@pytest.mark.parametrize("valid, unexplained", [(True, False), (True, True), (False, False)])
def test_drawing_in_yuv420_equals_drawing_in_bgr_and_converting(body, scene, valid, unexplained):
    """The overlay draws on the decoder's yuv420p pictures; the result must be the BGR drawing's, converted."""
    _, pixels = scene
    x, y = np.meshgrid(np.linspace(0, 1, WIDTH), np.linspace(0, 1, HEIGHT))
    frame = np.stack([60 + 120 * x, 40 + 150 * y, 200 - 120 * x * y], axis=2).astype(np.uint8)  # textured
    points = pixels + [25.0, -10.0]  # off centre, so that the drawn box is not the whole frame
    keypoints = np.concatenate([points, np.full((len(points), 1), 0.9)], axis=1)
    arrows = np.stack([points[:4], points[:4] - [30.0, 70.0]], axis=1)  # long arrows: heads near the box edge
    contacts = np.array([True, False, True, False])  # filled and hollow markers
    drawing = (points, skeleton_edges(body), body.point_names, keypoints, contacts, arrows, valid, unexplained)

    expected_bgr = frame.copy()
    _draw_in_place(expected_bgr, *drawing)
    expected = av.VideoFrame.from_ndarray(expected_bgr, format="bgr24").reformat(format="yuv420p")
    picture = av.VideoFrame.from_ndarray(frame, format="bgr24").reformat(format="yuv420p")
    untouched = [plane.copy() for plane in yuv420_planes(picture)]
    _draw_yuv420(yuv420_planes(picture), YuvScratch(WIDTH, HEIGHT), *drawing)

    drawn_y, expected_y = yuv420_planes(picture)[0].astype(int), yuv420_planes(expected)[0].astype(int)
    # luma: the same strokes everywhere, to the rounding of anti-aliased edges (a stroke cut off differs by ~100)
    assert np.abs(drawn_y - expected_y).max() <= 6 and np.mean(np.abs(drawn_y - expected_y) > 2) < 0.001
    assert np.abs(drawn_y - untouched[0]).max() > 100  # and something was drawn
    for drawn, wanted in zip(yuv420_planes(picture)[1:], yuv420_planes(expected)[1:], strict=True):
        difference = np.abs(drawn.astype(int) - wanted)
        # chroma: averaged 2 x 2 here, filtered by swscale there: alike but at the strokes' edges
        assert difference.mean() < 1.0 and np.percentile(difference, 99) <= 12


def test_banners_are_drawn_in_their_own_band(body, scene):
    """A banner spans the width: drawn in one box with the skeleton, that box would reach from the skeleton to the
    frame's edge. Each banner has its band, even-aligned for the 2 x 2 chroma, the skeleton its own box."""
    _, pixels = scene
    points = pixels * 0.4 + [0.0, 10.0]  # a small skeleton near the top
    size, line = (WIDTH, HEIGHT), 2
    skeleton = _drawn_box(size, line, points, None, None, True)
    assert skeleton is not None and skeleton[3] < HEIGHT // 2
    for text, at_top in _banners(valid=True, unexplained=True) + _banners(valid=False, unexplained=True):
        x0, y0, x1, y1 = _banner_box(size, text, at_top)
        band = _banner_layout(text, WIDTH, HEIGHT)[-1]
        assert (x0, x1) == (0, WIDTH) and y1 - y0 in (band, band + 1) and y0 % 2 == 0 and y1 % 2 == 0
        assert (y0 == 0) if at_top else (y1 == HEIGHT)


def test_contacts_are_filled_only_while_in_contact(body, scene, video, tmp_path):
    _, pixels = scene
    contacts = np.zeros((FRAMES, 4), bool)
    contacts[:5, 0] = True  # left heel in contact for the first five frames
    out = tmp_path / "contacts.mp4"
    # No bones, so that the inside of a contact marker shows only the marker.
    render_overlay(video, out, np.tile(pixels, (FRAMES, 1, 1)), [], np.ones(FRAMES, bool), contacts=contacts,
                   labels=body.point_names)
    _, frames = decode(out)
    heel = pixels[body.point_index([CONTACT_POINTS[0]])[0]]
    blue, green, red = pixel(frames[0], heel)
    assert green > max(blue, red) + 60
    assert np.abs(pixel(frames[7], heel) - BACKGROUND).max() < 15


def test_max_width_scales_frames_and_points(body, scene, video, tmp_path):
    _, pixels = scene
    out = tmp_path / "small.mp4"
    render_overlay(video, out, np.tile(pixels, (FRAMES, 1, 1)), skeleton_edges(body), np.ones(FRAMES, bool),
                   labels=body.point_names, max_width=160)
    _, frames = decode(out)
    assert len(frames) == FRAMES and frames[0].shape == (120, 160, 3)
    index = {name: i for i, name in enumerate(body.point_names)}
    spine_middle = (pixels[index["pelvis"]] + pixels[index["neck"]]) / 4  # half the size
    assert pixel(frames[0], spine_middle).min() > BACKGROUND + 80


def test_too_short_video_writes_nothing(body, scene, video, tmp_path):
    _, pixels = scene
    out = tmp_path / "long.mp4"
    with pytest.raises(ValueError, match="fewer"):
        render_overlay(video, out, np.tile(pixels, (FRAMES + 5, 1, 1)), skeleton_edges(body),
                       np.ones(FRAMES + 5, bool))
    assert not out.exists()


@pytest.mark.slow
def test_result_figure_writes_a_png(body, scene, tmp_path):
    world, pixels = scene
    clip = world[None] + np.linspace(0.0, 1.0, 6)[:, None, None] * np.array([1.0, 0.5, 0.0])  # walking forward
    frame = np.full((HEIGHT, WIDTH, 3), BACKGROUND, np.uint8)
    out = tmp_path / "figure.png"
    result_figure(frame, pixels, skeleton_edges(body), clip, 2, out, labels=body.point_names)
    image = cv2.imread(str(out))
    assert image is not None and image.shape[1] > image.shape[0] > 200


def test_unexplained_frames_carry_a_bottom_banner_over_the_skeleton(body, scene, video, tmp_path):
    _, pixels = scene
    unexplained = np.zeros(FRAMES, bool)
    unexplained[6] = True
    out = tmp_path / "unexplained.mp4"
    render_overlay(video, out, np.tile(pixels, (FRAMES, 1, 1)), skeleton_edges(body), np.ones(FRAMES, bool),
                   labels=body.point_names, unexplained=unexplained)
    _, frames = decode(out)
    bottom = frames[6][-5:-2, :, :].reshape(-1, 3).mean(axis=0)
    assert np.abs(bottom - np.array(BANNER_COLOUR)).max() < 40
    assert np.abs(frames[5][-5:-2].astype(int) - BACKGROUND).max() < 15  # the other frames have none
    index = {name: i for i, name in enumerate(body.point_names)}
    spine_middle = (pixels[index["pelvis"]] + pixels[index["neck"]]) / 2
    assert pixel(frames[6], spine_middle).min() > BACKGROUND + 100  # the skeleton is still drawn
    with pytest.raises(ValueError, match="unexplained"):
        render_overlay(video, tmp_path / "bad.mp4", np.tile(pixels, (FRAMES, 1, 1)), [], np.ones(FRAMES, bool),
                       unexplained=np.zeros(FRAMES + 1, bool))


def test_non_finite_points_and_arrows_are_skipped_and_reported(body, scene, video, tmp_path):
    _, pixels = scene
    points = np.tile(pixels, (FRAMES, 1, 1))
    index = {name: i for i, name in enumerate(body.point_names)}
    points[2, index["left_knee"]] = np.nan
    points[4, index["neck"]] = [np.inf, 3.0]
    points[5, index["head"]] = [1e12, -1e12]  # finite but far beyond what cv2 can take
    valid = np.ones(FRAMES, bool)
    valid[8] = False
    points[8] = np.nan  # not reconstructed: banner, not a report
    arrows = np.tile(np.array([[[100.0, 200.0], [100.0, 120.0]]]), (FRAMES, 3, 1, 1))
    arrows[1, 0, 1] = np.nan
    arrows[3, 1, 1] = [np.inf, 0.0]
    arrows[7, 2, 1] = [1e15, 1e15]
    out = tmp_path / "nonfinite.mp4"
    report = render_overlay(video, out, points, skeleton_edges(body), valid, labels=body.point_names,
                            force_arrows=arrows)
    assert report.nonfinite_frames == [2, 4, 5]
    assert (report.frames, report.width, report.height) == (FRAMES, WIDTH, HEIGHT)
    _, frames = decode(out)
    assert len(frames) == FRAMES
    shin = (pixels[index["left_knee"]] + pixels[index["left_ankle"]]) / 2
    assert np.abs(pixel(frames[2], shin) - BACKGROUND).max() < 15  # the bone to the missing knee is not drawn
    assert pixel(frames[3], shin).max() > BACKGROUND + 60


def test_default_width_is_at_most_1280_pixels(body, tmp_path):
    wide = tmp_path / "wide.mp4"
    with VideoWriter(wide, FPS, 1600, 64, preset="ultrafast") as writer:
        for _ in range(3):
            writer.write(np.full((64, 1600, 3), BACKGROUND, np.uint8))
    report = render_overlay(wide, tmp_path / "out.mp4", np.zeros((3, 0, 2)), [], np.ones(3, bool))
    assert (report.width, report.height) == (1280, 52)  # 51 lines stretched to an even height for yuv420p
    _, frames = decode(tmp_path / "out.mp4")
    assert frames[0].shape == (52, 1280, 3)
    native = render_overlay(wide, tmp_path / "native.mp4", np.zeros((3, 0, 2)), [], np.ones(3, bool), max_width=None)
    assert native.width == 1600


def test_overlay_of_a_rotated_video_is_upright(tmp_path):
    from test_video_io import write_timed_video

    stored = np.full((48, 64, 3), BACKGROUND, np.uint8)
    video = write_timed_video(tmp_path / "phone.mp4", [stored] * 4, [0, 1, 2, 3], Fraction(1, 25), rotation_cw=90)
    point = np.array([[10.0, 50.0]])  # x, y in the upright 48 x 64 frame
    keypoints = np.tile(np.array([[[10.0, 50.0, 0.9]]]), (4, 1, 1))
    report = render_overlay(video, tmp_path / "overlay.mp4", np.tile(point, (4, 1, 1)), [], np.ones(4, bool),
                            keypoints=keypoints)
    assert (report.width, report.height) == (48, 64)
    _, frames = decode(tmp_path / "overlay.mp4")
    assert frames[0].shape == (64, 48, 3)
    assert pixel(frames[0], point[0]).max() > BACKGROUND + 80  # drawn where the upright frame has it
    assert np.abs(pixel(frames[0], np.array([38.0, 10.0])) - BACKGROUND).max() < 15


def test_overlay_job_renders_in_a_worker_and_cancels_without_leaving_a_file(body, scene, video, tmp_path):
    _, pixels = scene
    points = np.tile(pixels, (FRAMES, 1, 1))
    out = tmp_path / "job.mp4"
    with start_overlay(video, out, points, skeleton_edges(body), np.ones(FRAMES, bool)) as job:
        report = job.result()
    assert report.frames == FRAMES and out.is_file()

    cancelled = tmp_path / "cancelled.mp4"
    started = threading.Event()
    with pytest.raises(KeyboardInterrupt):
        with start_overlay(video, cancelled, points, skeleton_edges(body), np.ones(FRAMES, bool),
                           progress=lambda done, total: (started.set(), time.sleep(0.05))):
            started.wait(10)
            raise KeyboardInterrupt
    assert not cancelled.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["job.mp4"]

    failing = start_overlay(video, tmp_path / "long.mp4", np.tile(pixels, (FRAMES + 5, 1, 1)), [],
                            np.ones(FRAMES + 5, bool))
    with pytest.raises(ValueError, match="fewer"):
        failing.result()
