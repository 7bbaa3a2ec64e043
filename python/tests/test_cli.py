"""The module and the CLI give the same results for the same input and options."""
import importlib.util
import subprocess

import numpy as np
import pytest

import vdbrecon
from conftest import SOURCE_DIR, sphere


def run_cli(cli, *args):
    r = subprocess.run([cli, *map(str, args)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r


def assert_same_mesh(a, b):
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.normals, b.normals)


def test_reconstruct_equals_the_cli_on_a_sphere(cli, tmp_path):
    points, normals = sphere(20000, 0.5, centre=(1.0, 2.0, 3.0))
    src = tmp_path / "sphere.ply"
    vdbrecon.write_points(src, vdbrecon.PointCloud(points, normals))
    out = tmp_path / "cli.ply"
    run_cli(cli, src, "-o", out, "--voxel", "0.02", "--k", "12", "--min-weight", "0.1",
            "--max-gap", "3", "-q")
    mesh = vdbrecon.reconstruct(points, normals, voxel=0.02, k=12, min_weight=0.1, max_gap=3.0)
    assert len(mesh.faces) > 1000
    assert_same_mesh(vdbrecon.read_mesh(out), mesh)
    # The CLI's volume equals the one Python splats with the same options.
    r = vdbrecon.reconstruct(points, normals, voxel=0.02, k=12, min_weight=0.1, max_gap=3.0,
                             return_result=True)
    cli_volume = vdbrecon.read_volume(tmp_path / "cli.splat.vdb")
    for grid in ("sdf", "weight"):
        np.testing.assert_array_equal(cli_volume.to_arrays(grid)[1], r.volume.to_arrays(grid)[1])


def test_run_writes_the_same_files_as_the_cli(cli, tmp_path):
    src = SOURCE_DIR / "data" / "bunny_sample.ply"
    run_cli(cli, src, "-o", tmp_path / "cli.ply", "--mesher", "vdb", "--normals", "estimate",
            "--threads", "2", "-q")
    r = vdbrecon.run(src, tmp_path / "py.ply", method="vdb", mode="estimate", threads=2)
    assert r.vdb_path == str(tmp_path / "py.splat.vdb") and r.result.voxel_chosen
    assert (tmp_path / "py.splat.vdb").read_bytes() == (tmp_path / "cli.splat.vdb").read_bytes()
    a, b = vdbrecon.read_mesh(tmp_path / "cli.ply"), vdbrecon.read_mesh(tmp_path / "py.ply")
    assert_same_mesh(a, b)
    # ... and reconstruct() on the cloud read in Python gives that mesh too.
    cloud = vdbrecon.read_points(src).cloud
    m = vdbrecon.reconstruct(cloud, mode="estimate", method="vdb", threads=1)
    np.testing.assert_array_equal(m.faces, b.faces)
    np.testing.assert_allclose(m.vertices + np.asarray(m.origin, np.float32), b.vertices +
                               np.asarray(b.origin, np.float32), atol=1e-6)


def test_run_ascii_and_no_vdb(tmp_path):
    points, normals = sphere(3000)
    src = tmp_path / "s.ply"
    vdbrecon.write_points(src, vdbrecon.PointCloud(points, normals))
    r = vdbrecon.run(src, tmp_path / "o.ply", voxel=0.1, encoding="ascii", write_vdb=False)
    assert r.vdb_path == "" and not (tmp_path / "o.splat.vdb").exists()
    assert b"format ascii 1.0" in (tmp_path / "o.ply").read_bytes()[:200]
    with pytest.raises(vdbrecon.InvalidArgument, match="extension"):
        vdbrecon.run(src, tmp_path / "o.stl", voxel=0.1)


def test_run_with_closing_writes_the_same_files_as_the_cli(cli, tmp_path):
    points, normals = sphere(40000)
    keep = points[:, 1] <= 0.985  # a hole 7 voxels across in the top
    src = tmp_path / "capped.ply"
    vdbrecon.write_points(src, vdbrecon.PointCloud(points[keep], normals[keep]))
    run_cli(cli, src, "-o", tmp_path / "cli.ply", "--voxel", "0.05", "--close", "4",
            "--no-outliers", "-q")
    r = vdbrecon.run(src, tmp_path / "py.ply", voxel=0.05, hole_radius=4, outliers_enabled=False)
    assert r.closed_vdb_path == str(tmp_path / "py.closed.vdb")
    assert r.vdb_path == str(tmp_path / "py.splat.vdb")
    for suffix in ("splat.vdb", "closed.vdb"):
        assert (tmp_path / f"py.{suffix}").read_bytes() == \
            (tmp_path / f"cli.{suffix}").read_bytes(), suffix
    mesh = vdbrecon.read_mesh(tmp_path / "py.ply")
    assert_same_mesh(vdbrecon.read_mesh(tmp_path / "cli.ply"), mesh)
    assert vdbrecon.mesh_topology(mesh).boundary_edges == 0
    assert "fill" in vdbrecon.read_volume(r.closed_vdb_path).grids()
    assert r.result.timings[0].stage == "read" and "outliers" not in [
        t.stage for t in r.result.timings]
    plain = vdbrecon.run(src, tmp_path / "plain.ply", voxel=0.05)
    assert plain.closed_vdb_path == "" and not (tmp_path / "plain.closed.vdb").exists()


def canonical_mesh(m):
    """bench/mesh_diff.py's canonical form: a mesh whatever the order of its vertices and faces."""
    spec = importlib.util.spec_from_file_location("mesh_diff", SOURCE_DIR / "bench" / "mesh_diff.py")
    mesh_diff = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mesh_diff)
    return mesh_diff.canonical(m)


def test_tiles_give_the_untiled_mesh_and_the_cli_bytes(cli, tmp_path):
    src = SOURCE_DIR / "data" / "bunny_sample.ply"
    run_cli(cli, src, "-o", tmp_path / "cli.ply", "--tile", "40", "-q")
    assert not (tmp_path / "cli.splat.vdb").exists()  # a tiled run has no whole volume
    r = vdbrecon.run(src, tmp_path / "py.ply", tile=40)
    assert r.vdb_path == "" and r.result.tile == 40 and r.result.tiles > 1
    assert (tmp_path / "py.ply").read_bytes() == (tmp_path / "cli.ply").read_bytes()
    whole = vdbrecon.run(src, tmp_path / "whole.ply", write_vdb=False)
    a = canonical_mesh(vdbrecon.read_mesh(tmp_path / "whole.ply"))
    b = canonical_mesh(vdbrecon.read_mesh(tmp_path / "py.ply"))
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_allclose(a[0], b[0], atol=1e-6 * whole.result.voxel_size)
