"""The overlay rendered in two parts at once and joined without re-encoding: the same video as one part, and the
same behaviour on cancel, Ctrl-C, errors, short videos and non-finite inputs."""

from __future__ import annotations

import logging
import os
import threading
from fractions import Fraction

import av
import numpy as np
import pytest

from physmocap import cores
from physmocap.body.kinematics import forward_kinematics
from physmocap.body.model import build_body_model, template_lengths
from physmocap.io.video import PartsDiffer, VideoWriter, join_video_parts
from physmocap.viz import overlay
from physmocap.viz.overlay import OverlayCancelled, overlay_parts, render_overlay, skeleton_edges, start_overlay

WIDTH, HEIGHT, FRAMES, FPS = 160, 120, 40, 30.0
SPLIT = FRAMES // 2  # the second part's first frame (overlay._split_frame)


@pytest.fixture(scope="module")
def body():
    return build_body_model(template_lengths(1.7), 70)


@pytest.fixture(scope="module")
def points(body):
    """(FRAMES, P, 2) the rest pose seen from the front, swaying left and right."""
    world = forward_kinematics(body, body.rest_qpos).points[0]
    pixels = np.stack([WIDTH / 2 - 50 * world[:, 1], HEIGHT - 10 - 50 * world[:, 2]], axis=1)
    return pixels[None] + np.stack([20 * np.sin(np.arange(FRAMES) / 4.0), np.zeros(FRAMES)], axis=1)[:, None]


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """A bright bar moving across a gradient, a different place in each frame, so that frame order shows."""
    path = tmp_path_factory.mktemp("video") / "input.mp4"
    background = np.tile(np.linspace(40, 200, WIDTH, dtype=np.uint8)[None, :, None], (HEIGHT, 1, 3))
    with VideoWriter(path, FPS, WIDTH, HEIGHT, crf=12) as writer:
        for index in range(FRAMES):
            frame = background.copy()
            frame[:12, 4 * index: 4 * index + 4] = 255
            writer.write(frame)
    return path


def render(video, out, body, points, parts, **kwargs):
    return render_overlay(video, out, points, skeleton_edges(body), np.ones(len(points), bool),
                          labels=body.point_names, parts=parts, **kwargs)


def decoded(path) -> list[np.ndarray]:
    with av.open(str(path)) as container:
        return [frame.to_ndarray(format="bgr24") for frame in container.decode(container.streams.video[0])]


def test_two_parts_give_the_frames_of_one_part_in_a_valid_h264_mp4(video, body, points, tmp_path):
    done: list[int] = []
    one = render(video, tmp_path / "one.mp4", body, points, 1)
    two = render(video, tmp_path / "two.mp4", body, points, 2, progress=lambda n, total: done.append((n, total)))
    assert (one.parts, two.parts) == (1, 2)
    assert (two.frames, two.width, two.height) == (one.frames, one.width, one.height)
    assert done == [(n, FRAMES) for n in range(1, FRAMES + 1)]  # one count over both parts, finished once
    assert sorted(path.name for path in tmp_path.iterdir()) == ["one.mp4", "two.mp4"]  # no part files left

    single, joined = decoded(tmp_path / "one.mp4"), decoded(tmp_path / "two.mp4")
    assert len(joined) == len(single) == FRAMES
    for index, frame in enumerate(joined):
        differences = [np.abs(frame.astype(int) - other).mean() for other in single]
        assert int(np.argmin(differences)) == index  # the same order
        assert differences[index] < 1.5  # the encoder's noise: x264 CRF 23 on two different reference chains
    with av.open(str(tmp_path / "two.mp4")) as container:
        stream = container.streams.video[0]
        assert (stream.codec_context.name, stream.codec_context.pix_fmt) == ("h264", "yuv420p")
        assert stream.average_rate == Fraction(30) and stream.frames == FRAMES
        assert float(stream.duration * stream.time_base) == pytest.approx(FRAMES / FPS)
        with av.open(str(tmp_path / "one.mp4")) as reference:
            assert stream.codec_context.extradata == reference.streams.video[0].codec_context.extradata
        packets = [packet for packet in container.demux(stream) if packet.size]
    ticks = int(1 / (stream.average_rate * stream.time_base))
    assert [packet.pts for packet in packets] == [index * ticks for index in range(FRAMES)]
    assert np.all(np.diff([packet.dts for packet in packets]) > 0)
    assert [index for index, packet in enumerate(packets) if packet.is_keyframe] == [0, SPLIT]
    data = (tmp_path / "two.mp4").read_bytes()
    assert data.index(b"moov") < data.index(b"mdat")  # the index first, so that a browser plays while loading


def test_the_first_part_never_ends_on_a_keyframe():
    assert overlay._split_frame(FRAMES) == SPLIT
    for frames in (502, 503, 1002):  # the middle frame minus one a multiple of x264's keyframe interval
        split = overlay._split_frame(frames)
        assert (split - 1) % overlay.X264_KEYINT != 0 and abs(split - frames / 2) <= 1.5


def test_automatic_parts_need_enough_frames_two_cores_and_no_pool(monkeypatch):
    assert overlay_parts(1, 10_000) == 1 and overlay_parts(2, 3) == 2 and overlay_parts(2, 2) == 1
    assert overlay_parts(None, overlay.MIN_FRAMES_FOR_PARTS - 1) == 1
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    assert overlay_parts(None, overlay.MIN_FRAMES_FOR_PARTS) == 2
    monkeypatch.setattr(cores.multiprocessing, "parent_process", lambda: object())  # a pool worker
    assert overlay_parts(None, overlay.MIN_FRAMES_FOR_PARTS) == 1
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    monkeypatch.setattr(cores.multiprocessing, "parent_process", lambda: None)
    assert overlay_parts(None, overlay.MIN_FRAMES_FOR_PARTS) == 1
    with pytest.raises(ValueError, match="parts must be"):
        overlay_parts(3, 100)


def test_parts_that_cannot_be_joined_are_rendered_again_in_one_part(video, body, points, tmp_path, monkeypatch,
                                                                     caplog):
    def refuse(parts, path):
        raise PartsDiffer(f"{parts[1]}: its codec parameters differ.")

    monkeypatch.setattr(overlay, "join_video_parts", refuse)
    done: list[tuple[int, int]] = []
    with caplog.at_level(logging.WARNING, logger=overlay.__name__):
        report = render(video, tmp_path / "out.mp4", body, points, 2, progress=lambda n, total: done.append((n, total)))
    assert report.parts == 1 and len(decoded(tmp_path / "out.mp4")) == FRAMES
    assert "rendering it again in one part" in caplog.text
    counts = [n for n, _ in done]
    assert counts == sorted(counts) and done[-1] == (2 * FRAMES, 2 * FRAMES)  # never backwards
    assert sorted(path.name for path in tmp_path.iterdir()) == ["out.mp4"]


def test_join_refuses_parts_that_differ_and_writes_nothing(tmp_path):
    def part(name, width, frames):
        with VideoWriter(tmp_path / name, FPS, width, HEIGHT, preset="ultrafast") as writer:
            for level in range(frames):
                writer.write(np.full((HEIGHT, width, 3), 50 + level, np.uint8))
        return tmp_path / name

    first, narrower, single = part("a.mp4", WIDTH, 5), part("b.mp4", WIDTH - 16, 5), part("c.mp4", WIDTH, 1)
    with pytest.raises(PartsDiffer, match="codec parameters differ"):
        join_video_parts([first, narrower], tmp_path / "joined.mp4")
    with pytest.raises(PartsDiffer, match="ends on a keyframe"):
        join_video_parts([single, first], tmp_path / "joined.mp4")
    assert not (tmp_path / "joined.mp4").exists()
    assert join_video_parts([first, part("d.mp4", WIDTH, 4)], tmp_path / "joined.mp4") == 9
    assert len(decoded(tmp_path / "joined.mp4")) == 9
    assert sorted(path.name for path in tmp_path.iterdir()) == ["a.mp4", "b.mp4", "c.mp4", "d.mp4", "joined.mp4"]


@pytest.mark.parametrize("frames", [FRAMES + 5, 3 * FRAMES])  # the video ends in the second part / the first
def test_a_video_shorter_than_the_drawing_writes_nothing(video, body, points, tmp_path, frames):
    longer = np.concatenate([points] * 3)[:frames]
    with pytest.raises(ValueError, match=f"has {FRAMES} frames, fewer than the {frames} to draw"):
        render(video, tmp_path / "out.mp4", body, longer, 2)
    assert list(tmp_path.iterdir()) == []


def test_cancel_stops_both_parts_and_leaves_no_file(video, body, points, tmp_path):
    cancel = threading.Event()

    def cancel_after_a_few(done, total):
        if done == 6:
            cancel.set()

    with pytest.raises(OverlayCancelled):
        render(video, tmp_path / "out.mp4", body, points, 2, progress=cancel_after_a_few, cancel=cancel)
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_and_errors_in_either_part_stop_both_and_leave_no_file(video, body, points, tmp_path):
    calling_thread = threading.get_ident()

    def interrupt_in(thread_is_calling: bool, error: BaseException):
        def progress(done, total):
            if done > 4 and (threading.get_ident() == calling_thread) == thread_is_calling:
                raise error
        return progress

    with pytest.raises(KeyboardInterrupt):  # Ctrl-C arrives in the calling thread, which draws the first part
        render(video, tmp_path / "out.mp4", body, points, 2, progress=interrupt_in(True, KeyboardInterrupt()))
    with pytest.raises(RuntimeError, match="disk full"):  # the second part's worker fails
        render(video, tmp_path / "out.mp4", body, points, 2, progress=interrupt_in(False, RuntimeError("disk full")))
    assert list(tmp_path.iterdir()) == []
    assert not [thread for thread in threading.enumerate() if thread.name.startswith("physmocap-overlay")]


def test_overlay_job_in_two_parts_cancels_on_ctrl_c(video, body, points, tmp_path):
    started = threading.Event()
    with pytest.raises(KeyboardInterrupt):
        with start_overlay(video, tmp_path / "job.mp4", points, skeleton_edges(body), np.ones(FRAMES, bool), parts=2,
                           progress=lambda done, total: started.set()):
            started.wait(10)
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_non_finite_inputs_are_reported_alike_in_two_parts(video, body, points, tmp_path):
    broken = points.copy()
    broken[[3, SPLIT, FRAMES - 1], 5] = np.nan
    broken[SPLIT + 2, 7] = [1e12, -1e12]
    arrows = np.tile(np.array([[[60.0, 100.0], [60.0, 60.0]]]), (FRAMES, 2, 1, 1))
    arrows[SPLIT + 1, 0, 1] = np.inf
    one = render(video, tmp_path / "one.mp4", body, broken, 1, force_arrows=arrows)
    two = render(video, tmp_path / "two.mp4", body, broken, 2, force_arrows=arrows)
    assert two.nonfinite_frames == one.nonfinite_frames == [3, SPLIT, SPLIT + 2, FRAMES - 1]
    single, joined = decoded(tmp_path / "one.mp4"), decoded(tmp_path / "two.mp4")
    assert len(joined) == FRAMES
    assert max(np.abs(a.astype(int) - b).mean() for a, b in zip(single, joined, strict=True)) < 1.5
