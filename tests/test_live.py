import numpy as np

from physmocap.config import Settings
from physmocap.kinematics.stage import fit_motion
from physmocap.live import stream_capture
from conftest import DEMO_VIDEO


def test_streaming_capture_equals_the_causal_fit_of_the_same_detections():
    settings = Settings(online=True)
    poses = []
    report = stream_capture(str(DEMO_VIDEO), settings, max_frames=45, on_pose=lambda i, q, details: poses.append(i))
    assert report.observations.num_frames == 45
    assert sorted(poses) == list(range(45))
    # Warm-up holds back the calibration frames; afterwards every frame is delivered in order.
    assert poses[report.warmup_frames:] == list(range(report.warmup_frames, 45))
    batch = fit_motion(report.observations, settings)
    assert np.allclose(batch.qpos, report.motion.qpos, atol=1e-9)
    assert report.frames_per_second > 0 and np.isfinite(report.latency_median_ms)


def test_streaming_physics_equals_the_physics_stage_on_the_same_inputs():
    from physmocap.dynamics.stage import run_physcap

    settings = Settings(online=True).replace("physics", method="physcap")
    report = stream_capture(str(DEMO_VIDEO), settings, max_frames=40)
    assert report.physics is not None and report.contacts.shape == (40, 4)
    batch = run_physcap(report.motion.body, report.motion.qpos, report.observations.fps, report.contacts,
                        report.stationary, settings.physics)
    assert np.allclose(batch.qpos, report.physics.qpos, atol=1e-9)
    assert np.allclose(batch.grf, report.physics.grf, atol=1e-6)
