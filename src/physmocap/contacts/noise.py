"""MediaPipe Pose's errors, measured on the shared real videos, as a `NoiseModel` for synthetic training data.

`scripts/measure_mediapipe_noise.py` re-measures every number below and says in its docstring exactly how; the
data were 38 s of valid video (2568 frames of 8 tracks): tai-chi (24 fps), basketball (12 fps), a man on a box
doing jumping jacks and a flip and a woman walking past in side view (30 fps), and four synchronised, calibrated
views of a man balancing on one leg (Pose2Sim, 60 fps), detected with the pipeline's settings (model_complexity
1, smoothing on, 640 px wide frames).

What was measured (2D in person heights, 3D in metres):
- keypoint_sd 0.0015: white frame-to-frame jitter from robust second differences (0.0008-0.0018 on the slow
  videos, 0.0036-0.0053 where fast true motion leaks in: basketball at 12 fps, the flip).
- keypoint_drift_sd 0.0083, keypoint_drift_seconds 0.12: the time-varying part of the error against the
  triangulation of the four Pose2Sim views (0.0085, less the white part), correlated over 0.12 s. Cross-check:
  feet that the hand labels mark as planted spread by 0.0082 (robust SD, 22 runs of 8+ frames, 377 frames).
  Not modelled: the static part of that error (0.016, each landmark's offset in each view, joint definition and
  calibration together) and its total (0.023), which move no keypoint from frame to frame; 15 % gross errors
  (over 0.1 person heights), mostly one view's left/right foot swap for 0.3 s, which foot swaps stand for.
- keypoint_drift_length 0.166 person heights: that time-varying 2D error is shared by landmarks near each other
  along the skeleton (a limb's landmarks move together): correlation exp(-distance / 0.166) fits the 528 pairs'
  correlations (ankle-heel 0.9, knee-ankle 0.6, across the body about 0; per view 0.13-0.20).
- landmark_sd 0.0026 m: white jitter of landmarks_3d across the image (x, y); along depth it is 0.0060 m.
- landmark_drift_sd 0.026 m, landmark_drift_seconds 0.15: the time-varying error of landmarks_3d (after a
  least-squares scale) against the triangulated, hip-centred points in each camera's axes (x, y; 0.030 m along
  depth), less the white part; their static part is 0.034 m. Correlated along the skeleton over 0.271 person
  heights (landmark_drift_length; per view 0.23-0.40).
- depth_scale_sd 0.18, depth_scale_seconds 0.15: per frame, the least-squares factor between MediaPipe's
  hip-relative depths and the triangulated ones varies with this robust SD about its median. The median itself
  is 0.66: MediaPipe flattens the body along the depth axis by a third, a bias that NoiseModel cannot express and
  that the contact networks do not see (they read 2D keypoints only).
- confidence_mean 0.953, confidence_sd 0.085: visibility of keypoints with visibility >= 0.5.
- dropout_per_second 0.088, dropout_seconds 0.48, dropout_confidence 0.78: runs of visibility under 0.5 (110
  episodes, half of them in the flip video; hands and wrists 75, elbows 13, knees 8, feet 14); their mean
  visibility is 0.39. Jitter inside them is 0.0056 person heights (2D) and 0.011 m (3D) more than outside
  (dropout_keypoint_sd, dropout_landmark_sd).
- foot_swaps_per_second 0.27, foot_swap_seconds 0.42: 10 left/right foot swap episodes found by frame-to-frame
  matching (5 in the flip video, 2 in the side-view walk, 3 in Pose2Sim view 2, where looking at the frames
  confirms that the labels of the standing and the raised foot trade places for 0.3 s); durations are capped at
  1 s.
- landmark_scale: each landmark's robust multi-view error over their mean (face 0.74-0.96, hands and wrists
  1.3-1.5, legs and feet 0.92-1.13).
"""

from __future__ import annotations

from dataclasses import replace

from ..mocap.synthetic import NoiseModel

MEDIAPIPE_NOISE = NoiseModel(
    keypoint_sd=0.0015,
    keypoint_drift_sd=0.0083,
    keypoint_drift_seconds=0.117,
    keypoint_drift_length=0.166,
    landmark_sd=0.0026,
    landmark_drift_sd=0.0262,
    landmark_drift_seconds=0.15,
    landmark_drift_length=0.271,
    depth_scale_sd=0.184,
    depth_scale_seconds=0.15,
    confidence_mean=0.953,
    confidence_sd=0.085,
    dropout_per_second=0.0884,
    dropout_seconds=0.483,
    dropout_confidence=0.783,
    dropout_keypoint_sd=0.0056,
    dropout_landmark_sd=0.0108,
    foot_swaps_per_second=0.2651,
    foot_swap_seconds=0.415,
    landmark_scale=(
        0.95, 0.89, 0.88, 0.88, 0.91, 0.93, 0.96, 0.74, 0.76, 0.96, 0.93,
        0.86, 0.98, 1.08, 1.17, 0.76, 1.31, 0.79, 1.47, 0.76, 1.53, 0.75, 1.45,
        0.99, 1.05, 1.0, 1.05, 1.07, 0.92, 1.13, 1.03, 0.97, 1.09,
    ),
)
"""MediaPipe Pose (full model, smoothing on) as measured on the shared videos; see the module docstring."""

TRAINING_NOISE = replace(MEDIAPIPE_NOISE, keypoint_drift_length=0.0, landmark_drift_length=0.0)
"""MEDIAPIPE_NOISE with drifts independent per landmark: the errors the shipped contact networks were trained and
are tested on, measured before the correlation along the skeleton was (docs/decisions/noise-correlation.md)."""
