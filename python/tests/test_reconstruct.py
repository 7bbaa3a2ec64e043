"""reconstruct() on analytic input: the mesh must be the sphere the points came from."""
import math

import numpy as np
import pytest

import vdbrecon
from conftest import sphere

VOXEL = 0.04


def test_sphere_mesh_lies_on_the_sphere(sphere_result):
    mesh = sphere_result.mesh
    assert isinstance(mesh, vdbrecon.Mesh)
    assert mesh.vertices.dtype == np.float32 and mesh.vertices.shape[1] == 3
    assert mesh.faces.dtype == np.int32 and mesh.faces.shape[1] == 3
    assert len(mesh.faces) > 5000
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert np.abs(radius - 1.0).max() < 0.1 * VOXEL
    assert mesh.faces.min() >= 0 and mesh.faces.max() < len(mesh.vertices)


def test_sphere_mesh_is_closed_outward_and_has_the_right_volume(sphere_result):
    t = vdbrecon.mesh_topology(sphere_result.mesh)
    assert t.watertight() and t.boundary_edges == 0 and t.nonmanifold_edges == 0
    assert t.components == 1 and t.euler == 2
    assert t.signed_volume == pytest.approx(4.0 / 3.0 * math.pi, rel=0.01)
    assert t.area == pytest.approx(4.0 * math.pi, rel=0.01)


def test_sphere_vertex_normals_point_outward(sphere_result):
    mesh = sphere_result.mesh
    assert mesh.normals is not None and mesh.normals.shape == mesh.vertices.shape
    radial = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    assert (np.sum(mesh.normals * radial, axis=1) > 0.99).all()
    # Faces counter-clockwise seen from outside: their normals agree with the radial direction.
    v = mesh.vertices[mesh.faces]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert (np.sum(n * v.mean(axis=1), axis=1) > 0).all()


def test_result_carries_the_volume_and_statistics(sphere_result):
    r = sphere_result
    assert r.voxel_size == VOXEL and not r.voxel_chosen
    assert r.volume.voxel_size == pytest.approx(VOXEL)
    assert r.splat.active_voxels == r.volume.active_voxels > 0
    assert r.normals.estimated == 0  # the given normals were kept
    assert not r.outliers.removed.any() and len(r.outliers.removed) == 20000  # no stray point
    assert r.closed_volume is None  # closing is off by default
    assert [t.stage for t in r.timings] == ["outliers", "normals", "splat", "mesh", "clean"]


def test_estimated_normals_give_the_same_surface():
    points, _ = sphere(20000)
    mesh = vdbrecon.reconstruct(points, voxel=VOXEL, mode="estimate")
    t = vdbrecon.mesh_topology(mesh)
    assert t.watertight() and t.signed_volume == pytest.approx(4.0 / 3.0 * math.pi, rel=0.01)


def test_automatic_voxel_is_the_point_spacing():
    points, normals = sphere(20000)
    r = vdbrecon.reconstruct(points, normals, return_result=True)
    assert r.voxel_chosen
    spacing = math.sqrt(4 * math.pi / 20000)  # about the mean kNN distance
    assert 0.5 * spacing < r.voxel_size < 1.5 * spacing


def test_options_reach_their_stage():
    points, normals = sphere(5000)
    coarse = vdbrecon.reconstruct(points, normals, voxel=0.1)
    fine = vdbrecon.reconstruct(points, normals, voxel=0.05)
    assert len(fine.faces) > 3 * len(coarse.faces)
    no_normals = vdbrecon.reconstruct(points, normals, voxel=0.1, mesh_normals=False)
    assert no_normals.normals is None and len(no_normals.faces) == len(coarse.faces)
    # Every vertex farther from the data than allowed: every face trimmed, the options reached
    # MeshOptions.
    heavy = vdbrecon.reconstruct(points, normals, voxel=0.1, max_gap=1e-6, max_gap_spacings=0)
    assert len(heavy.faces) == 0


def test_library_warnings_reach_python_logging(caplog):
    points, normals = sphere(5000)
    with caplog.at_level("INFO", logger="vdbrecon"):
        mesh = vdbrecon.reconstruct(points, normals, voxel=0.1, max_gap=1e-6,
                                    max_gap_spacings=0)
    assert len(mesh.faces) == 0
    warnings = [r for r in caplog.records if r.name == "vdbrecon" and r.levelname == "WARNING"]
    assert any("surface is empty" in r.getMessage() for r in warnings)


def test_colors_are_splatted():
    points, normals = sphere(5000)
    colors = np.tile(np.array([[1.0, 0.5, 0.25]], np.float32), (5000, 1))
    r = vdbrecon.reconstruct(points, normals, colors, voxel=0.1, return_result=True)
    assert "color" in r.volume.grids()
    _, values = r.volume.to_arrays("color")
    np.testing.assert_allclose(values, np.tile([1.0, 0.5, 0.25], (len(values), 1)), atol=1e-5)


def test_stage_by_stage_equals_reconstruct(sphere_cloud, sphere_result):
    points, normals = sphere_cloud
    cloud = vdbrecon.remove_outliers(points, normals).cloud
    n = vdbrecon.estimate_normals(cloud)
    assert n.estimated == 0 and n.scales.shape == (len(cloud),) == (len(points),)
    s = vdbrecon.splat(cloud, n.normals, scales=n.scales, voxel=VOXEL)
    m = vdbrecon.clean_mesh(vdbrecon.extract_mesh(s.volume).mesh).mesh
    np.testing.assert_array_equal(m.vertices, sphere_result.mesh.vertices)
    np.testing.assert_array_equal(m.faces, sphere_result.mesh.faces)


def test_evaluate_against_itself_and_a_shifted_copy(sphere_result):
    mesh = sphere_result.mesh
    same = vdbrecon.evaluate(mesh, mesh, samples=20000)
    assert same.chamfer_l1 < 1e-6 and same.fscores[0].fscore == pytest.approx(1.0)
    shifted = vdbrecon.Mesh(mesh.vertices + np.float32(0.01), mesh.faces)
    far = vdbrecon.evaluate(shifted, mesh, samples=20000, taus=[0.001, 0.1])
    assert 0.002 < far.chamfer_l1 < 0.02
    assert far.fscores[0].fscore < 0.5 and far.fscores[1].fscore == pytest.approx(1.0)


def test_gil_is_released_during_the_work():
    import threading
    import time
    points, normals = sphere(60000)
    ticks = []
    stop = threading.Event()

    def ticker():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.001)

    t = threading.Thread(target=ticker)
    t.start()
    start = time.perf_counter()
    vdbrecon.reconstruct(points, normals, voxel=0.01, threads=1)
    end = time.perf_counter()
    stop.set()
    t.join()
    during = [x for x in ticks if start < x < end]
    # With the GIL held for the whole call the ticker could not run at all meanwhile.
    assert end - start > 0.05
    assert len(during) > 10


def test_shared_bunny_scans_match_the_reference(shared_data):
    scans = shared_data / "stanford_bunny" / "bun_scans_aligned.ply"
    gt = shared_data / "stanford_bunny" / "bun_zipper_gt.ply"
    cloud = vdbrecon.read_points(scans).cloud
    mesh = vdbrecon.reconstruct(cloud, voxel=0.0005)
    e = vdbrecon.evaluate(mesh, gt, samples=200000, taus=[0.0005])
    assert e.fscores[0].fscore > 0.99
    assert e.chamfer_l1 < 0.0001


def test_memory_budget_refuses_before_the_grids_or_tiles():
    points, normals = sphere(5000)
    with pytest.raises(ValueError, match=r"needs about .* Hint: --voxel"):
        vdbrecon.reconstruct(points, normals, voxel=0.005, max_memory=20 << 20, auto_tile=False)
    mesh = vdbrecon.reconstruct(points, normals, voxel=0.05, max_memory=20 << 20)
    assert len(mesh.faces) > 1000
    # Over the budget without auto_tile=False the run tiles itself and says why.
    points, normals = sphere(20000)
    r = vdbrecon.reconstruct(points, normals, voxel=0.01, max_memory=100 << 20,
                             return_result=True)
    assert r.tile > 0 and "more than the budget" in r.auto_tiled
    whole = vdbrecon.reconstruct(points, normals, voxel=0.01, return_result=True)
    assert whole.tile == 0 and whole.auto_tiled == ""
    assert len(whole.mesh.faces) == len(r.mesh.faces)


def test_presumming_by_keyword():
    """aggregate= presums the splat's samples (off by default); Fusion's aggregate= is its depth
    option, as --aggregate in `vdbrecon fuse`."""
    points, normals = sphere(20000, 1.0)
    plain = vdbrecon.splat(points, normals, voxel=0.05)
    summed = vdbrecon.splat(points, normals, voxel=0.05, aggregate=1.5)
    assert plain.points == plain.samples == 20000
    assert summed.samples == 20000 and summed.points < 15000
    assert summed.updates < plain.updates
    with pytest.raises(ValueError, match="depth.aggregate"):
        vdbrecon.Fusion(0.05, aggregate=9.0)
    with pytest.raises(ValueError, match="splat.aggregate"):
        vdbrecon.splat(points, normals, voxel=0.05, aggregate=9.0)
