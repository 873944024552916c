"""Contact sheets for labelling foot contacts by eye: crops around the feet of consecutive frames, tiled.

Each tile is one frame, cropped around both feet (the same box size on the whole sheet: the feet's largest spread
plus a tenth of the person's height each side), with the frame number;
the crop follows the feet's centre in each frame; and, optionally, the detected left foot keypoints in red and the right in blue (to see the detector's sides;
labels are by the person's real left and right). Usage:

    .venv/bin/python scripts/contact_sheets.py VIDEO_NAME FIRST LAST [--step N] [--columns C] [--marks] [--full]

VIDEO_NAME is a name of physmocap.contacts.real_videos.REAL_VIDEOS; writes runs/contacts/sheets/<name>_<first>.png.
--full tiles whole frames (scaled) instead of foot crops.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import physmocap  # noqa: F401
import cv2
import numpy as np

from physmocap.contacts.real_videos import REAL_VIDEOS, cached_detection
from physmocap.landmarks import LANDMARK_INDEX

REPO = Path(__file__).resolve().parents[1]
VIDEOS = REPO.parent / "shared" / "data" / "videos"
FEET = [LANDMARK_INDEX[f"{s}_{p}"] for s in ("left", "right") for p in ("ankle", "heel", "foot_index")]
TILE = 300


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("name")
    parser.add_argument("first", type=int)
    parser.add_argument("last", type=int)
    parser.add_argument("--step", type=int, default=1)
    parser.add_argument("--columns", type=int, default=6)
    parser.add_argument("--marks", action="store_true")
    parser.add_argument("--full", action="store_true")
    args = parser.parse_args()
    video = next(v for v in REAL_VIDEOS if v.name == args.name)
    obs = cached_detection(video, VIDEOS, REPO / "runs" / "contacts" / "detections")
    wanted = set(range(args.first, min(args.last, obs.num_frames - 1) + 1, args.step))
    capture = cv2.VideoCapture(str(VIDEOS / video.relative_path))
    tiles, index = [], 0
    # one crop box for the whole sheet, so that heights compare between tiles
    frames = sorted(wanted)
    xy = obs.keypoints_2d[frames][:, FEET, :2][obs.valid[frames]]
    height = np.percentile(np.ptp(obs.keypoints_2d[obs.valid][:, :, 1], axis=1), 90)
    extent = np.max(np.ptp(xy, axis=1), axis=0)  # largest per-frame spread of the feet, (x, y)
    half = np.array([max(0.6 * extent[0] + height / 10, height / 5), max(0.6 * extent[1] + height / 10, height / 8)])
    while True:
        ok, frame = capture.read()
        if not ok or index > args.last:
            break
        if index in wanted:
            if args.marks and obs.valid[index]:
                for k, colour in zip(FEET, [(0, 0, 255)] * 3 + [(255, 0, 0)] * 3):
                    x, y = obs.keypoints_2d[index, k, :2]
                    cv2.circle(frame, (int(x), int(y)), max(2, int(height / 150)), colour, -1)
            if args.full:
                crop = frame
            else:
                pad = int(height)
                padded = cv2.copyMakeBorder(frame, pad, pad, pad, pad, cv2.BORDER_CONSTANT)
                feet = obs.keypoints_2d[index if obs.valid[index] else frames[0], FEET, :2]
                centre = 0.5 * (feet.min(axis=0) + feet.max(axis=0)) - np.array([0.0, 0.3 * half[1]])
                (x0, y0), (x1, y1) = (centre - half).astype(int) + pad, (centre + half).astype(int) + pad
                crop = padded[y0:y1, x0:x1]
            size = (TILE, int(round(TILE * half[1] / half[0]))) if not args.full else (TILE, int(TILE * crop.shape[0] / crop.shape[1]))
            tile = cv2.resize(crop, size)
            cv2.putText(tile, str(index), (4, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 255, 255), 2)
            tiles.append(tile)
        index += 1
    while len(tiles) % args.columns:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[i : i + args.columns]) for i in range(0, len(tiles), args.columns)]
    out = REPO / "runs" / "contacts" / "sheets" / f"{args.name}_{args.first}{'_full' if args.full else ''}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.vstack(rows))
    print(out)


if __name__ == "__main__":
    main()
