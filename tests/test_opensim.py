"""OpenSim exports read back by OpenSim itself (the `opensim` package: TRC and STO/MOT adapters, Storage,
ExternalLoads) and by a plain numpy parse of the declared columns.

OpenSim is driven in a separate process: its wheel bundles CasADi 3.7, which, once loaded, breaks the import of
the CasADi 3.8 the trajectory optimisation uses in the same process."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys

import numpy as np
import pytest

from physmocap.export import export_result
from physmocap.io.opensim import MIN_COP_FORCE, foot_wrenches, write_grf_mot, write_trc
from physmocap.result import save_result
from test_export import synthetic_result

pytestmark = pytest.mark.slow  # OpenSim reads the files back, in processes of its own

# OpenSim (X, Y, Z) = world (x, z, -y).
WORLD_TO_OPENSIM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
CONTACTS = ("left_heel", "left_toe", "right_heel", "right_toe")
FEET = {"l": (0, 1), "r": (2, 3)}

needs_opensim = pytest.mark.skipif(importlib.util.find_spec("opensim") is None, reason="opensim is not installed")

OPENSIM_READER = r"""
import json, sys
import opensim
opensim.Logger.removeFileSink()  # OpenSim would otherwise write opensim.log into the working directory
opensim.Logger.setLevelString("warn")
kind, path = sys.argv[1], sys.argv[2]
if kind == "trc":
    table = opensim.TimeSeriesTableVec3(path)
    rows = (table.getRowAtIndex(i) for i in range(table.getNumRows()))
    out = dict(labels=[str(n) for n in table.getColumnLabels()], units=table.getTableMetaDataAsString("Units"),
               rate=float(table.getTableMetaDataAsString("DataRate")), times=list(table.getIndependentColumn()),
               values=[[[row[m][k] for k in range(3)] for m in range(table.getNumColumns())] for row in rows])
elif kind == "mot":
    table = opensim.TimeSeriesTable(path)
    out = dict(size=opensim.Storage(path).getSize(), labels=[str(n) for n in table.getColumnLabels()],
               columns={str(n): table.getDependentColumn(n).to_numpy().tolist() for n in table.getColumnLabels()})
else:
    loads = opensim.ExternalLoads(path, True)
    forces = [loads.get(i) for i in range(loads.getSize())]
    out = dict(file=loads.getDataFileName(), size=loads.getSize(), forces=[dict(
        body=f.get_applied_to_body(), force_in=f.get_force_expressed_in_body(),
        point_in=f.get_point_expressed_in_body(), force=f.get_force_identifier(), point=f.get_point_identifier(),
        torque=f.get_torque_identifier()) for f in forces])
print(json.dumps(out))
"""


def opensim_read(kind: str, path) -> dict:
    """What OpenSim itself reads from a .trc ("trc"), .mot ("mot") or ExternalLoads .xml ("loads") file."""
    done = subprocess.run([sys.executable, "-c", OPENSIM_READER, kind, str(path)], capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    folder = tmp_path_factory.mktemp("opensim")
    result = synthetic_result(frames=50)
    save_result(folder / "result.npz", result)
    files = export_result(folder / "result.npz", "opensim", folder)
    return result, files


def numpy_table(path: str, header_lines: int) -> tuple[list[str], np.ndarray]:
    """The label line right after `header_lines` lines and the numbers below it."""
    with open(path) as f:
        lines = f.read().splitlines()
    return lines[header_lines].split("\t"), np.loadtxt(path, skiprows=header_lines + 1, ndmin=2)


@needs_opensim
def test_markers_read_by_opensim_within_1mm(exported):
    result, files = exported
    table = opensim_read("trc", files["trc"])
    names = [str(n) for n in result["joint_names"]]
    assert table["labels"] == names
    assert table["units"] == "m"
    assert table["rate"] == pytest.approx(float(result["fps"]))
    times = np.array(table["times"])
    np.testing.assert_allclose(times, np.arange(len(times)) / float(result["fps"]), atol=1e-6)
    expected = result["joints_world"] @ WORLD_TO_OPENSIM.T
    assert np.abs(np.array(table["values"]) - expected).max() < 1e-3


def test_markers_read_by_numpy_and_in_millimetres(exported, tmp_path):
    result, files = exported
    values = np.loadtxt(files["trc"], skiprows=6)
    T, P = result["joints_world"].shape[:2]
    assert values.shape == (T, 2 + 3 * P)
    np.testing.assert_array_equal(values[:, 0], np.arange(1, T + 1))
    metres = values[:, 2:].reshape(T, P, 3)
    assert np.abs(metres - result["joints_world"] @ WORLD_TO_OPENSIM.T).max() < 1e-3
    write_trc(tmp_path / "mm.trc", result["joints_world"], result["joint_names"], 30.0, units="mm")
    millimetres = np.loadtxt(tmp_path / "mm.trc", skiprows=6)[:, 2:].reshape(T, P, 3)
    assert np.abs(millimetres / 1000 - metres).max() < 1e-5
    if importlib.util.find_spec("opensim") is not None:
        assert opensim_read("trc", tmp_path / "mm.trc")["units"] == "mm"


@needs_opensim
def test_grf_read_by_opensim_within_10mN(exported):
    result, files = exported
    table = opensim_read("mot", files["mot"])
    assert table["size"] == len(result["grf"])
    column = table["columns"]
    names = [str(n) for n in result["joint_names"]]
    contact_points = result["joints_world"][:, [names.index(n) for n in CONTACTS]]
    for side, (heel, toe) in FEET.items():
        force = np.stack([column[f"{side}_ground_force_v{a}"] for a in "xyz"], 1)
        point = np.stack([column[f"{side}_ground_force_p{a}"] for a in "xyz"], 1)
        torque = np.stack([column[f"{side}_ground_torque_{a}"] for a in "xyz"], 1)
        expected_force = (result["grf"][:, heel] + result["grf"][:, toe]) @ WORLD_TO_OPENSIM.T
        assert np.abs(force - expected_force).max() < 0.01
        # The file's wrench (force at point plus torque) is the wrench of the heel and toe forces.
        moment = sum(np.cross(contact_points[:, i] @ WORLD_TO_OPENSIM.T, result["grf"][:, i] @ WORLD_TO_OPENSIM.T)
                     for i in (heel, toe))
        assert np.abs(np.cross(point, force) + torque - moment).max() < 0.01
        pressing = force[:, 1] >= MIN_COP_FORCE
        assert pressing.any() and (~pressing).any()
        np.testing.assert_allclose(point[:, 1], 0.0, atol=1e-9)  # on the floor
        np.testing.assert_allclose(torque[pressing][:, [0, 2]], 0.0, atol=0.01)  # a free moment only


def test_grf_columns_by_numpy(exported):
    result, files = exported
    labels, values = numpy_table(files["mot"], 6)
    assert labels[0] == "time" and len(labels) == 19 == values.shape[1]
    header = open(files["mot"]).read().splitlines()[:6]
    assert header[1:] == ["version=1", f"nRows={len(result['grf'])}", "nColumns=19", "inDegrees=no", "endheader"]
    vertical = values[:, labels.index("r_ground_force_vy")] + values[:, labels.index("l_ground_force_vy")]
    np.testing.assert_allclose(vertical, result["grf"][..., 2].sum(axis=1), atol=0.01)


@needs_opensim
def test_external_loads_name_the_mot_columns(exported):
    _, files = exported
    loads = opensim_read("loads", files["external_loads"])
    labels = set(opensim_read("mot", files["mot"])["labels"])
    assert loads["file"] == "grf.mot" and loads["size"] == 2
    for force in loads["forces"]:
        assert force["force_in"] == force["point_in"] == "ground"
        for identifier in (force["force"], force["point"], force["torque"]):
            assert {identifier + a for a in "xyz"} <= labels
    assert {force["body"] for force in loads["forces"]} == {"calcn_r", "calcn_l"}


def test_centre_of_pressure_of_two_vertical_forces():
    """Heel 300 N at x = 0, toe 100 N at x = 0.2: the centre of pressure lies at x = 0.05, no torque."""
    grf = np.zeros((1, 4, 3))
    grf[0, 2, 2], grf[0, 3, 2] = 300.0, 100.0
    points = np.zeros((1, 4, 3))
    points[0, 3, 0] = 0.2
    points[0, 2:, 1] = -0.1
    force, point, torque = foot_wrenches(grf, points)["r"]
    np.testing.assert_allclose(force[0], [0.0, 0.0, 400.0])
    np.testing.assert_allclose(point[0], [0.05, -0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(torque[0], 0.0, atol=1e-12)


def test_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="shape"):
        write_grf_mot(tmp_path / "g.mot", np.zeros((3, 2, 3)), np.zeros((3, 4, 3)), 30.0)
    with pytest.raises(ValueError, match="units"):
        write_trc(tmp_path / "m.trc", np.zeros((2, 1, 3)), ["a"], 30.0, units="inch")
    with pytest.raises(ValueError, match="unique"):
        write_trc(tmp_path / "m.trc", np.zeros((2, 2, 3)), ["a", "a"], 30.0)
    assert not list(tmp_path.iterdir())
