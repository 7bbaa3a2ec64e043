"""Textures for planar regions (issue 25 point 4): a painted box through reconstruct() and
texture_regions() in Python, and the textured OBJ opened by Blender 3.4 headless (its own OBJ
importer, python/tools/blender_texture_check.py): one object, the atlas loaded into the
material, and the texel under each sampled polygon's texture coordinates the colour of the
surface there (the painted function on the box; the scan's point colours on the table scene of
../shared/data)."""
import json
import pathlib
import shutil
import subprocess

import numpy as np
import pytest

import vdbrecon

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "tools" / "blender_texture_check.py"


def paint(p):
    """The colour painted on the box: smooth, different on every face."""
    k = 2.0 * np.pi / 0.6
    return np.stack([0.5 + 0.4 * np.sin(k * p[:, 0]), 0.5 + 0.4 * np.sin(k * p[:, 1] + 1.0),
                     0.5 + 0.4 * np.cos(k * p[:, 2])], axis=1).astype(np.float32)


def painted_box(n=40000, seed=4):
    """A unit box turned off the axes, sampled uniformly at random, exact normals, painted."""
    rng = np.random.default_rng(seed)
    axis = rng.integers(0, 3, n)
    side = rng.integers(0, 2, n).astype(np.float64)
    p = rng.random((n, 3))
    p[np.arange(n), axis] = side
    normal = np.zeros((n, 3))
    normal[np.arange(n), axis] = 2.0 * side - 1.0
    a, b = 0.5, 0.3  # a rotation about z, then about x
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    rot = rx @ rz
    p = (p - 0.5) @ rot.T
    normal = normal @ rot.T
    return p.astype(np.float32), normal.astype(np.float32), paint(p)


def texel_at(image, uv):
    h, w, _ = image.shape
    x = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
    y = np.clip(((1.0 - uv[:, 1]) * h).astype(int), 0, h - 1)
    return image[y, x] / 255.0


def test_painted_box_in_python():
    p, n, c = painted_box()
    voxel = 0.025
    r = vdbrecon.reconstruct(p, n, c, voxel=voxel, mesh_method="dc", planes_enabled=True,
                             texture_enabled=True, outliers_enabled=False, return_result=True)
    atlas, mesh = r.texture, r.mesh
    assert atlas.regions == len(r.planes.planes) == 6
    assert atlas.image.shape == (atlas.height, atlas.width, 3) and atlas.image.dtype == np.uint8
    assert atlas.uv.shape == (len(mesh.faces), 3, 2) and not np.isnan(atlas.uv).any()
    assert atlas.texel == pytest.approx(voxel / 2)
    # The texel under each face's centre has the painted colour of the surface there.
    centre = mesh.vertices[mesh.faces].mean(axis=1)
    got = texel_at(atlas.image, atlas.uv.mean(axis=1))
    err = np.abs(got - paint(centre))
    print(f"colour error mean {err.mean():.4f} max {err.max():.4f}")
    assert err.mean() < 0.02 and err.max() < 0.1, (err.mean(), err.max())
    # texture_regions() on the same mesh, planes and points makes the same atlas.
    again = vdbrecon.texture_regions(mesh, r.planes.planes, p, voxel, colors=c)
    assert np.array_equal(again.image, atlas.image)
    assert np.array_equal(again.uv, atlas.uv)
    with pytest.raises(vdbrecon.InvalidArgument, match="colours"):
        vdbrecon.texture_regions(mesh, r.planes.planes, p, voxel)


def blender_texture(obj, tmp_path):
    r = subprocess.run(["blender", "-b", "--factory-startup", "--python", str(SCRIPT), "--",
                        str(obj), "-", "200"], capture_output=True, text=True, timeout=300,
                       cwd=tmp_path)
    line = [l for l in r.stdout.splitlines() if l.startswith("BLENDER_TEXTURE ")]
    assert r.returncode == 0 and line, r.stdout[-2000:] + r.stderr[-2000:]
    return json.loads(line[0][len("BLENDER_TEXTURE "):])


def check_blender_sees(info, obj, png):
    """One object with every face, a UV layer, and the atlas loaded into a textured material."""
    faces = sum(1 for l in open(obj) if l.startswith("f "))
    assert info["objects"] == 1 and info["polygons"] == faces and info["uv_layers"] == 1
    images = [m["image"] for m in info["materials"] if m["image"]]
    assert len(images) == 1 and images[0]["has_data"] and images[0]["linked"]
    size = png.read_bytes()[16:24]
    assert images[0]["size"] == [int.from_bytes(size[:4], "big"), int.from_bytes(size[4:], "big")]
    assert len(info["samples"]) >= 100
    s = np.array(info["samples"])
    return s[:, :3], s[:, 3:6]


@pytest.mark.skipif(shutil.which("blender") is None, reason="blender is not installed")
def test_blender_shows_the_painted_box(tmp_path, cli):
    p, n, c = painted_box()
    vdbrecon.write_points(tmp_path / "box.ply", vdbrecon.PointCloud(p, normals=n, colors=c))
    subprocess.run([cli, tmp_path / "box.ply", "-o", tmp_path / "box.obj", "--voxel", "0.025",
                    "--mesher", "dc", "--texture", "-q", "--no-vdb"], check=True)
    info = blender_texture(tmp_path / "box.obj", tmp_path)
    centre, colour = check_blender_sees(info, tmp_path / "box.obj", tmp_path / "box.texture.png")
    # The PLY stores 8-bit colours: compare with the painted function to that precision.
    err = np.abs(colour - paint(centre))
    print(f"colour error mean {err.mean():.4f} max {err.max():.4f}")
    assert err.mean() < 0.02 and err.max() < 0.1, (err.mean(), err.max())


@pytest.mark.skipif(shutil.which("blender") is None, reason="blender is not installed")
def test_blender_opens_the_textured_table_scene(tmp_path, cli, shared_data):
    scan = shared_data / "pcl_kinect" / "table_scene_mug_stereo_textured.ply"
    subprocess.run([cli, scan, "-o", tmp_path / "table.obj", "--voxel", "0.008", "--texture",
                    "-q", "--no-vdb"], check=True)
    info = blender_texture(tmp_path / "table.obj", tmp_path)
    centre, colour = check_blender_sees(info, tmp_path / "table.obj",
                                        tmp_path / "table.texture.png")
    # Each sampled texel against the mean colour of the scan's points within a texel (4 mm) of
    # its point; the same texels against other samples' points as the control.
    cloud = vdbrecon.read_points(scan).cloud
    pos, col = cloud.positions + np.asarray(cloud.origin, np.float32), cloud.colors
    near = []
    for q in centre:
        d2 = ((pos - q) ** 2).sum(axis=1)
        near.append(col[d2 < 0.004 ** 2].mean(axis=0) if (d2 < 0.004 ** 2).any() else
                    col[np.argmin(d2)])
    near = np.array(near)
    err = np.abs(colour - near).mean()
    control = np.abs(colour - np.roll(near, len(near) // 2, axis=0)).mean()
    print(f"table scene texels vs points: mean error {err:.4f}, control {control:.4f}")
    assert err < 0.06 and err < 0.4 * control, (err, control)
