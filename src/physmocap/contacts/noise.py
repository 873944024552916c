"""MediaPipe Pose's errors, measured on the shared real videos, as a `NoiseModel` for synthetic training data.

`scripts/measure_mediapipe_noise.py` re-measures every number below and says in its docstring exactly how; the
data were 34 s of valid video (2426 frames): tai-chi (24 fps), basketball (12 fps), a man on a box doing jumping
jacks and a flip (30 fps), and four synchronised, calibrated views of a man balancing on one leg (Pose2Sim, 60
fps), detected with the pipeline's settings (model_complexity 1, smoothing on, 640 px wide frames).

What was measured (2D in person heights, 3D in metres):
- keypoint_sd 0.0014: white frame-to-frame jitter from robust second differences (0.0008-0.0017 on the slow
  videos, 0.0036-0.0053 where fast true motion leaks in: basketball at 12 fps, the flip).
- keypoint_drift_sd 0.0226, keypoint_drift_seconds 0.18: the rest of the total error (robust median error 0.023
  person heights, about 18 px for a person 780 px tall) against the triangulation of the four Pose2Sim views,
  whose residual autocorrelation falls to 1/e after 0.18 s. An upper bound: the calibration's own inconsistency
  (about 15 px on the face landmarks too) is included. 15 % of those 2D residuals exceed 0.1 person heights: gross
  errors, mostly one view's left/right foot swap for 0.3 s while the man stood on one leg.
- landmark_sd 0.0026 m: white jitter of landmarks_3d across the image (x, y); along depth it is 0.0061 m.
- landmark_drift_sd 0.057 m, landmark_drift_seconds 0.18: robust error of landmarks_3d (after a least-squares
  scale) against the triangulated, hip-centred points in each camera's axes, less the white part; along depth
  the robust error is 0.153 m.
- depth_scale_sd 0.18, depth_scale_seconds 0.15: per frame, the least-squares factor between MediaPipe's
  hip-relative depths and the triangulated ones varies with this robust SD about its median. The median itself
  is 0.66: MediaPipe flattens the body along the depth axis by a third, a bias that NoiseModel cannot express and
  that the contact networks do not see (they read 2D keypoints only).
- confidence_mean 0.953, confidence_sd 0.083: visibility of keypoints with visibility >= 0.5.
- dropout_per_second 0.073, dropout_seconds 0.49, dropout_confidence 0.77: runs of visibility under 0.5 (82
  episodes, 55 of them in the flip video; hands and elbows 57, left foot and knees 25); their mean visibility
  is 0.38. Jitter inside them is
  0.0061 person heights (2D) and 0.0117 m (3D) more than outside (dropout_keypoint_sd, dropout_landmark_sd).
- foot_swaps_per_second 0.24, foot_swap_seconds 0.51: 8 left/right foot swap episodes found by frame-to-frame
  matching (5 in the flip video, 3 in Pose2Sim view 2, where looking at the frames confirms that the labels of
  the standing and the raised foot trade places for 0.3 s); durations over 1 s are capped.
- landmark_scale: each landmark's robust multi-view error over their mean (face 0.74-0.96, hands and wrists
  1.3-1.5, legs and feet 0.92-1.13).
"""

from __future__ import annotations

from ..mocap.synthetic import NoiseModel

MEDIAPIPE_NOISE = NoiseModel(
    keypoint_sd=0.0014,
    keypoint_drift_sd=0.0226,
    keypoint_drift_seconds=0.183,
    landmark_sd=0.0026,
    landmark_drift_sd=0.057,
    landmark_drift_seconds=0.183,
    depth_scale_sd=0.184,
    depth_scale_seconds=0.15,
    confidence_mean=0.953,
    confidence_sd=0.083,
    dropout_per_second=0.0733,
    dropout_seconds=0.492,
    dropout_confidence=0.766,
    dropout_keypoint_sd=0.0061,
    dropout_landmark_sd=0.0117,
    foot_swaps_per_second=0.2361,
    foot_swap_seconds=0.51,
    landmark_scale=(
        0.95, 0.89, 0.88, 0.88, 0.91, 0.93, 0.96, 0.74, 0.76, 0.96, 0.93,
        0.86, 0.98, 1.08, 1.17, 0.76, 1.31, 0.79, 1.47, 0.76, 1.53, 0.75, 1.45,
        0.99, 1.05, 1.0, 1.05, 1.07, 0.92, 1.13, 1.03, 0.97, 1.09,
    ),
)
"""MediaPipe Pose (full model, smoothing on) as measured on the shared videos; see the module docstring."""
