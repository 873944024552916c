"""Repeated pictures: frames that show the picture of an earlier frame again, as a video converted to a higher
frame rate does (each picture shown 2-5 times), or a variable-rate video made constant. A repeated picture holds
no new observation at its own time, and MediaPipe, tracking from its last result, detects it a few pixels
elsewhere (5-26 px on hybrik_taiji's repeats): the motion becomes steps with jitter, which the physics cannot
follow (docs/decisions/repeated-pictures.md). Detection marks them (`picture_unchanged`); offline capture
replaces their detections by the straight line, in time, between the pictures around them
(`interpolate_repeated`). Pure numpy and OpenCV on images and observations.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from ..motion import Observations, valid_runs

UNCHANGED_LEVEL = 0.5
"""Mean absolute change of the person's box, in 8-bit levels per channel, below which a frame repeats the last new
picture. x264's repeats of one picture differ by 0.10 (median) to 0.43 (99th percentile); new pictures of a
moving person by 1.6 at the 1st percentile; a still person's new pictures may fall below, where the straight line
between the pictures around them is what the detections would have said."""
BOX_MARGIN = 0.1  # of the larger side of the person's keypoints' box, added on each side: the limbs' edges


def person_box(keypoints: np.ndarray, image_size: tuple[int, int]) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) pixels, inside the image of `image_size` (width, height): the box of keypoints (K, 3)
    (x, y px) grown by BOX_MARGIN; empty (x1 <= x0) when the keypoints lie outside the image."""
    width, height = image_size
    low, high = keypoints[:, :2].min(axis=0), keypoints[:, :2].max(axis=0)
    margin = BOX_MARGIN * float((high - low).max())
    x0, y0 = np.floor(np.maximum(low - margin, 0)).astype(int)
    x1, y1 = np.ceil(np.minimum(high + margin + 1, (width, height))).astype(int)
    return int(x0), int(y0), int(x1), int(y1)


def picture_change(previous: np.ndarray, frame: np.ndarray, box: tuple[int, int, int, int]) -> float:
    """Mean absolute difference, in 8-bit levels per channel, of `frame` (H, W, 3) uint8 from `previous` (same
    shape) inside `box` (x0, y0, x1, y1); infinite where the box is empty or the shapes differ."""
    x0, y0, x1, y1 = box
    if x1 <= x0 or y1 <= y0 or previous.shape != frame.shape:
        return float("inf")
    # every other row: half the cost, and still tens of thousands of pixels for a person of a hundred rows
    change = cv2.mean(cv2.absdiff(frame[y0:y1:2, x0:x1], previous[y0:y1:2, x0:x1]))
    return float(np.mean(change[:3]))


def picture_unchanged(previous: np.ndarray, frame: np.ndarray, box: tuple[int, int, int, int]) -> bool:
    """True when `frame` shows the picture `previous` again inside `box`: a change under UNCHANGED_LEVEL."""
    return picture_change(previous, frame, box) < UNCHANGED_LEVEL


class RepeatMarker:
    """Marks, frame by frame, the valid frames that show the last new picture of a valid frame again
    (`picture_unchanged` inside the person's box); holds that one decoded picture. The comparison is with the last
    new picture, not the frame before, so that a slow change that builds up over several frames starts a new
    picture once it reaches UNCHANGED_LEVEL."""

    def __init__(self, image_size: tuple[int, int]):
        self.image_size = image_size
        self._last_picture: np.ndarray | None = None

    def repeated(self, frame: np.ndarray, keypoints: np.ndarray, reason: str) -> bool:
        """True where `frame` (H, W, 3) uint8, whose detection is keypoints (K, 3) px (invalid: reason not ""),
        repeats the last new picture."""
        repeated = (not reason and self._last_picture is not None
                    and picture_unchanged(self._last_picture, frame, person_box(keypoints, self.image_size)))
        if not repeated:
            self._last_picture = None if reason else frame
        return repeated


def interpolate_repeated(obs: Observations) -> Observations:
    """`obs` with the keypoints and landmarks of each run of repeated frames (obs.repeated, valid) on the straight
    line, in time, from the new picture before the run to the one after it; held at the picture before where the
    run ends the clip or meets an invalid frame. The picture before a run is its first showing, so each picture
    stands at the time it was first shown. Unchanged (the same object) without repeated frames."""
    repeated = obs.repeated & obs.valid
    if not repeated.any():
        return obs
    keypoints, landmarks = obs.keypoints_2d.copy(), obs.landmarks_3d.copy()
    for start, stop in valid_runs(repeated):
        before, after = start - 1, stop
        if before < 0 or not obs.valid[before]:
            continue  # no picture before the run to stand for it: its detections are kept
        if after < obs.num_frames and obs.valid[after]:
            share = ((np.arange(start, stop) - before) / (after - before))[:, None, None]
        else:
            share = np.zeros((stop - start, 1, 1))
            after = before
        for values in (keypoints, landmarks):
            values[start:stop] = (1 - share) * values[before] + share * values[after]
    return dataclasses.replace(obs, keypoints_2d=keypoints, landmarks_3d=landmarks)
