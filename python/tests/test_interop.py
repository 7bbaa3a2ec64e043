"""The .vdb files with the real clients: pyopenvdb (python3-openvdb) and vdb_print
(libopenvdb-tools). Blender is checked by python/tools/interop_check.sh (too slow for here)."""
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import vdbrecon
from conftest import sphere

pyopenvdb = pytest.importorskip("pyopenvdb", reason="python3-openvdb is not installed")

# (name, pyopenvdb class, grid class) of every grid in <out>.splat.vdb.
GRIDS = [("sdf", "FloatGrid", "level set"), ("weight", "FloatGrid", "unknown"),
         ("nearest", "Vec3SGrid", "unknown"), ("density", "FloatGrid", "fog volume"),
         ("color", "Vec3SGrid", "unknown")]


@pytest.fixture(scope="module")
def splat_vdb(tmp_path_factory, cli):
    d = tmp_path_factory.mktemp("interop")
    points, normals = sphere(20000, 0.5)
    colors = (0.5 + 0.5 * normals).astype(np.float32)
    src = d / "ball.ply"
    vdbrecon.write_points(src, vdbrecon.PointCloud(points, normals, colors))
    subprocess.run([cli, src, "-o", d / "ball.ply.out.ply", "--voxel", "0.02", "-q"], check=True)
    return d / "ball.ply.out.splat.vdb"


def test_pyopenvdb_reads_every_grid_with_names_classes_and_values(splat_vdb):
    grids, meta = pyopenvdb.readAll(str(splat_vdb))
    assert sorted(g.name for g in grids) == sorted(n for n, _, _ in GRIDS)
    assert meta["creator"].startswith("vdbrecon ")
    ours = vdbrecon.read_volume(splat_vdb)
    by_name = {g.name: g for g in grids}
    for name, cls, grid_class in GRIDS:
        g = by_name[name]
        assert type(g).__name__ == cls, name
        assert g.gridClass == grid_class, name
        assert g.transform.voxelSize()[0] == pytest.approx(0.02)
        coords, values = ours.to_arrays(name)
        assert g.activeVoxelCount() == len(coords), name
        acc = g.getConstAccessor()
        pick = np.random.default_rng(1).choice(len(coords), 2000, replace=False)
        got = np.array([acc.getValue(tuple(int(x) for x in coords[i])) for i in pick])
        np.testing.assert_array_equal(got, values[pick])
        assert all(acc.isValueOn(tuple(int(x) for x in coords[i])) for i in pick[:100])
    assert by_name["sdf"].background == pytest.approx(ours.background)
    # sdf on the sphere of radius 0.5: its value at the voxel nearest (0.5, 0, 0) is ~0.
    assert abs(by_name["sdf"].getConstAccessor().getValue((25, 0, 0))) < 0.002


def test_to_and_from_pyopenvdb(splat_vdb):
    volume = vdbrecon.read_volume(splat_vdb)
    grids = vdbrecon.to_pyopenvdb(volume)
    assert sorted(grids) == sorted(n for n, _, _ in GRIDS)
    assert isinstance(grids["sdf"], pyopenvdb.FloatGrid)
    a = vdbrecon.extract_mesh(volume).mesh
    b = vdbrecon.extract_mesh(grids).mesh  # pyopenvdb grids in
    np.testing.assert_array_equal(a.faces, b.faces)
    only_sdf = vdbrecon.extract_mesh(grids["sdf"]).mesh  # no weight/nearest: nothing trimmed
    assert len(only_sdf.faces) >= len(a.faces)
    assert grids["sdf"].name == "sdf"


@pytest.mark.parametrize("order", ["pyopenvdb, vdbrecon", "vdbrecon, pyopenvdb"])
def test_import_in_either_order(order):
    code = (f"import {order}\n"
            "import numpy as np\n"
            "p = np.random.default_rng(0).normal(size=(2000, 3)).astype(np.float32)\n"
            "p /= np.linalg.norm(p, axis=1, keepdims=True)\n"
            "m = vdbrecon.reconstruct(p, p, voxel=0.1)\n"
            "g = pyopenvdb.FloatGrid(); g.name = 'x'\n"
            "print(len(m.faces) > 0, g.name)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env=dict(os.environ))
    assert r.returncode == 0, r.stderr  # a segfault shows as -11
    assert r.stdout.split() == ["True", "x"]


@pytest.mark.skipif(shutil.which("vdb_print") is None, reason="vdb_print (libopenvdb-tools) absent")
def test_vdb_print_lists_every_grid(splat_vdb):
    out = subprocess.run(["vdb_print", "-l", str(splat_vdb)], capture_output=True, text=True,
                         check=True).stdout
    for name, _, grid_class in GRIDS:
        assert f"Name: {name}\n" in out, name
    assert out.count("class: level set") == 1 and out.count("class: fog volume") == 1
    assert out.count("Tree_float_5_4_3") == 3 and out.count("Tree_vec3s_5_4_3") == 2


@pytest.mark.skipif(shutil.which("blender") is None, reason="blender is not installed")
def test_blender_loads_renders_and_meshes_the_file(tmp_path, cli):
    """Blender 3.4 headless (python/tools/blender_check.py): volume_import sees every grid,
    Cycles renders `density`, and VOLUME_TO_MESH on `sdf` gives vdbrecon's triangle count and
    bounding box (shifted by Blender's half voxel). python/tools/interop_check.sh does the same
    at full resolution, plus the bunny sample."""
    import json
    import pathlib
    voxel = 0.04
    points, normals = sphere(8000, 0.5)
    src = tmp_path / "ball.ply"
    vdbrecon.write_points(src, vdbrecon.PointCloud(points, normals))
    subprocess.run([cli, src, "-o", tmp_path / "out.ply", "--voxel", str(voxel), "-q"], check=True)
    mesh = vdbrecon.read_mesh(tmp_path / "out.ply")
    png = tmp_path / "density.png"
    script = pathlib.Path(__file__).resolve().parents[1] / "tools" / "blender_check.py"
    r = subprocess.run(["blender", "-b", "--factory-startup", "--python", str(script), "--",
                        str(tmp_path / "out.splat.vdb"), str(png), "4", "25"],
                       capture_output=True, text=True, timeout=300)
    line = [l for l in r.stdout.splitlines() if l.startswith("BLENDER_CHECK ")]
    assert r.returncode == 0 and line, r.stdout[-2000:] + r.stderr[-2000:]
    info = json.loads(line[0][len("BLENDER_CHECK "):])
    assert {g["name"]: g["data_type"] for g in info["grids"]} == {
        "sdf": "FLOAT", "weight": "FLOAT", "density": "FLOAT", "nearest": "VECTOR_FLOAT"}
    assert png.stat().st_size > 1000
    assert info["mesh"]["triangles"] == len(mesh.faces) > 1000
    lo = np.array(info["mesh"]["bbox_min"]) - voxel / 2
    hi = np.array(info["mesh"]["bbox_max"]) - voxel / 2
    np.testing.assert_allclose(lo, mesh.vertices.min(axis=0), atol=1e-5)
    np.testing.assert_allclose(hi, mesh.vertices.max(axis=0), atol=1e-5)
