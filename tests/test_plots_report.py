"""Plots, report.html with the run's metrics, and the ground reaction force arrows of the overlay video."""

from __future__ import annotations

import json
from html.parser import HTMLParser
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from physmocap.export import export_result
from physmocap.io.video import VideoWriter
from physmocap.result import save_result
from physmocap.viz.overlay import FORCE_COLOUR, draw_overlay, force_arrow_scale, force_arrows_2d, render_overlay
from physmocap.viz.plots import PLOT_FILES, write_plots
from physmocap.viz.report import floor_sentence, run_metrics, write_report, write_report_parts
from physmocap.viz.viewer import write_viewer
from test_export import synthetic_result


@pytest.fixture(scope="module")
def result():
    return synthetic_result(frames=60)


def test_plots_are_pngs_with_content(result, tmp_path):
    paths = write_plots(result, tmp_path)
    assert set(paths) == set(PLOT_FILES)
    for path in paths.values():
        image = cv2.imread(path)
        assert image is not None and image.shape[1] > 600 and image.std() > 10


def test_grf_plot_without_physics_shows_the_implied_force(tmp_path):
    paths = write_plots(synthetic_result(frames=20, with_physics=False), tmp_path)
    assert cv2.imread(paths["grf"]) is not None


def test_metrics_of_the_synthetic_walk(result):
    rows = {m.key: m for m in run_metrics(result)}
    # The synthetic keypoints are the projected points moved by (1.5, 1.5) px.
    assert rows["reprojection_error"].final == pytest.approx(1.5 * np.sqrt(2), abs=0.01)
    assert rows["reprojection_error"].kinematic > rows["reprojection_error"].final
    assert rows["mean_acceleration"].kinematic > rows["mean_acceleration"].final  # the kinematic motion jitters
    solved = rows["grf_mean_percent_bw"].final
    flight = ~result["contacts"].any(axis=1)
    expected = 100 * np.linalg.norm(result["grf"].sum(axis=1), axis=1).mean() / (result["body_mass"] * 9.81)
    assert solved == pytest.approx(expected) and 0 < solved < 110 and flight.any()
    assert rows["grf_ballistic_percent_bw"].final == 0.0
    assert rows["grf_mean_percent_bw"].kinematic is None
    assert 0.0 <= rows["com_over_support_percent"].final <= 100.0
    for key in ("floating_percent", "penetration_percent", "skate_percent", "pnp_percent"):
        assert 0.0 <= rows[key].final <= 100.0


class _Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.targets: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.targets += [value for name, value in attrs if name in ("href", "src")]


def test_report_links_every_output_and_shows_the_metrics(result, tmp_path):
    save_result(tmp_path / "result.npz", result)
    for to in ("bvh", "glb", "opensim"):
        export_result(tmp_path / "result.npz", to, tmp_path)
    write_viewer(result, tmp_path / "viewer.html")
    files = write_report(tmp_path, result)
    page = Path(files["report"]).read_text()
    parser = _Links()
    parser.feed(page)
    for name in ("viewer.html", "result.npz", "motion.bvh", "motion.glb", "markers.trc", "grf.mot",
                 "external_loads.xml", "metrics.json", "plots/grf.png", "plots/contacts.png",
                 "plots/foot_heights.png"):
        assert name in parser.targets
    assert all((tmp_path / target).is_file() for target in parser.targets)
    assert "overlay.mp4" not in parser.targets  # not in this folder, so not linked
    metrics = json.loads(Path(files["metrics"]).read_text())
    assert f"{metrics['reprojection_error']['final']:.3g}" in page
    assert "mean joint acceleration" in page and "implied GRF" in page


def test_report_says_which_floor_and_whether_it_is_trusted(result, tmp_path):
    """The page names the floor the motion stands on; one the run did not trust says so and how to give it."""
    def with_floor(**confidence):
        return dict(result, floor_confidence=np.array(json.dumps(confidence)))

    trusted = floor_sentence(with_floor(trusted=True, source="contacts", prior_disagreement_degrees=2.0))
    assert trusted.startswith("Floor: fitted to the feet in contact") and "not trusted" not in trusted
    untrusted = with_floor(trusted=False, source="posture", inlier_fraction=0.7, tilt_spread_degrees=9.9,
                           prior_disagreement_degrees=35.3)
    page = Path(write_report(tmp_path, untrusted)["report"]).read_text()
    assert "level with the person's own vertical" in page and "not trusted" in page
    assert "leant 35 degrees" in page and "--floor" in page
    assert floor_sentence({}) == ""
    assert "&lt;b&gt;" in floor_sentence(with_floor(trusted=True, source="<b>"))  # a foreign file's words, escaped


def test_force_arrows_point_along_the_force():
    project = lambda p: p[..., :2] * 100 + 200  # noqa: E731 - orthographic top view, 100 px per metre
    points = np.zeros((1, 4, 3))
    forces = np.zeros((1, 4, 3))
    forces[0, 0] = [686.7, 0.0, 0.0]  # one body weight of a 70 kg person, forwards
    forces[0, 1] = [0.5, 0.0, 0.0]  # below the drawing threshold
    arrows = force_arrows_2d(points, forces, project, force_arrow_scale(70.0, 1.75))
    np.testing.assert_allclose(arrows[0, 0], [[200.0, 200.0], [270.0, 200.0]])
    assert np.isnan(arrows[0, 1]).all() and np.isnan(arrows[0, 2]).all()
    image = draw_overlay(np.zeros((400, 400, 3), np.uint8), np.zeros((0, 2)), [], force_arrows=arrows[0])
    drawn = np.all(np.abs(image.astype(int) - FORCE_COLOUR) < 40, axis=2)
    assert drawn[200, 210:265].all() and not drawn[:, :195].any()


def test_overlay_video_draws_force_arrows(tmp_path):
    frames, size = 4, (160, 120)
    with VideoWriter(tmp_path / "input.mp4", 25.0, *size) as writer:
        for _ in range(frames):
            writer.write(np.full((size[1], size[0], 3), 60, np.uint8))
    arrows = np.tile(np.array([[[40.0, 60.0], [120.0, 60.0]]]), (frames, 1, 1, 1))
    render_overlay(tmp_path / "input.mp4", tmp_path / "overlay.mp4", np.zeros((frames, 0, 2)), [],
                   np.ones(frames, bool), force_arrows=arrows)
    with av.open(str(tmp_path / "overlay.mp4")) as container:
        last = [f.to_ndarray(format="bgr24") for f in container.decode(video=0)][-1]
    assert np.abs(last[60, 50:110].astype(int) - FORCE_COLOUR).max() < 60
    with pytest.raises(ValueError, match="force_arrows"):
        render_overlay(tmp_path / "input.mp4", tmp_path / "bad.mp4", np.zeros((frames, 0, 2)), [],
                       np.ones(frames, bool), force_arrows=arrows[:, :, 0])


def test_report_page_from_parts_written_earlier_is_the_same(result, tmp_path):
    """The pipeline writes the plots and metrics within its outputs stage, the page after summary.json."""
    early, late = tmp_path / "early" / "run", tmp_path / "late" / "run"
    early.mkdir(parents=True)
    parts = write_report_parts(early, result)
    assert Path(parts.metrics_path).is_file() and all(Path(p).is_file() for p in parts.plots.values())
    assert not (early / "report.html").exists()
    files = write_report(early, result, parts)
    assert Path(files["report"]).read_text() == Path(write_report(late, result)["report"]).read_text()
