"""Volumes across the Python boundary: .vdb files and numpy arrays of active voxels."""
import numpy as np
import pytest

import vdbrecon
from conftest import sphere


@pytest.fixture(scope="module")
def volume():
    points, normals = sphere(8000)
    return vdbrecon.splat(points, normals, voxel=0.08).volume


def test_volume_grids_and_arrays(volume):
    assert volume.grids() == ["sdf", "weight", "nearest", "density"]
    coords, sdf = volume.to_arrays("sdf")
    assert len(coords) == volume.active_voxels > 0
    world = np.asarray(volume.origin) + volume.voxel_size * coords
    # The sdf is the signed distance to the unit sphere near the surface.
    near = np.abs(sdf) < volume.voxel_size
    err = np.abs(np.linalg.norm(world[near], axis=1) - 1.0 - sdf[near])
    assert err.max() < 0.1 * volume.voxel_size
    _, weight = volume.to_arrays("weight")
    assert (weight >= 0.05).all()  # active = valid: weight >= min_weight
    dcoords, density = volume.to_arrays("density")
    assert density.min() > 0 and density.max() <= 1
    inside = np.linalg.norm(np.asarray(volume.origin) + volume.voxel_size * dcoords, axis=1) < 0.8
    assert np.all(density[inside] == 1.0)
    _, nearest = volume.to_arrays("nearest")
    assert nearest.shape == (len(coords), 3)
    with pytest.raises(vdbrecon.InvalidArgument, match="no grid 'color'"):
        volume.to_arrays("color")


def test_vdb_round_trip(volume, tmp_path):
    path = tmp_path / "sphere.splat.vdb"
    vdbrecon.write_volume(path, volume)
    back = vdbrecon.read_volume(path)
    assert back.voxel_size == pytest.approx(volume.voxel_size)
    assert back.grids() == volume.grids()
    assert back.metadata == volume.metadata and "kernel" in back.metadata
    for grid in ("sdf", "weight", "nearest", "density"):
        c0, v0 = volume.to_arrays(grid)
        c1, v1 = back.to_arrays(grid)
        np.testing.assert_array_equal(c0, c1)
        np.testing.assert_array_equal(v0, v1)
    m0 = vdbrecon.extract_mesh(volume).mesh
    m1 = vdbrecon.extract_mesh(path).mesh  # a path works wherever a Volume does
    np.testing.assert_array_equal(m0.vertices, m1.vertices)
    np.testing.assert_array_equal(m0.faces, m1.faces)
    vdbrecon.write_volume(tmp_path / "again.vdb", back)
    assert (tmp_path / "again.vdb").read_bytes() == path.read_bytes()  # deterministic files


def test_volume_from_arrays_meshes_like_the_original(volume):
    coords, sdf = volume.to_arrays("sdf")
    _, weight = volume.to_arrays("weight")
    _, nearest = volume.to_arrays("nearest")
    rebuilt = vdbrecon.Volume.from_arrays(coords, sdf, voxel_size=volume.voxel_size,
                                          origin=volume.origin, weight=weight, nearest=nearest,
                                          background=volume.background)
    a = vdbrecon.extract_mesh(volume).mesh
    b = vdbrecon.extract_mesh(rebuilt).mesh
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-6)
    with pytest.raises(ValueError, match="rows"):
        vdbrecon.Volume.from_arrays(coords, sdf[:-1], voxel_size=0.1)
    with pytest.raises(vdbrecon.InvalidArgument, match="voxel_size"):
        vdbrecon.Volume.from_arrays(coords, sdf, voxel_size=0.0)


def test_read_volume_errors(tmp_path):
    with pytest.raises(vdbrecon.IoError):
        vdbrecon.read_volume(tmp_path / "none.vdb")
    junk = tmp_path / "junk.vdb"
    junk.write_bytes(b"not a vdb file at all")
    with pytest.raises(vdbrecon.FormatError, match="junk.vdb"):
        vdbrecon.read_volume(junk)
    with pytest.raises(TypeError, match="Volume, a .vdb path"):
        vdbrecon.extract_mesh(42)
