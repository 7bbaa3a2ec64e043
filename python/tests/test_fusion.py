"""vdbrecon.Fusion: numpy depth images with intrinsics and camera-to-world poses, as Open3D and
VDBFusion users write it; the depth images are rendered analytically (ray-sphere)."""
import math

import numpy as np
import pytest

import vdbrecon

W, H = 160, 120
F = 0.5 * W / math.tan(math.radians(25.0))
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1]])
CENTRE = np.array([0.3, -0.2, 1.5])
RADIUS = 0.5


def look_at(eye):
    """Camera-to-world, OpenCV axes, looking at CENTRE."""
    z = CENTRE - eye
    z /= np.linalg.norm(z)
    up = np.array([0.0, 1.0, 0.0]) if abs(z[2]) > 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m


def render_sphere(pose):
    """Planar depth of the sphere seen by the camera (0 where the ray misses)."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rays = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u, dtype=float)], -1)
    d = rays @ pose[:3, :3].T  # world directions, z-component 1 in the camera
    o = pose[:3, 3] - CENTRE
    a = (d * d).sum(-1)
    b = 2 * (d * o).sum(-1)
    c = o @ o - RADIUS ** 2
    disc = b * b - 4 * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)  # t = planar depth (ray z = 1)
    return np.where(disc > 0, t, 0.0).astype(np.float32)


def poses(n=20, distance=2.0):
    golden = math.pi * (3 - math.sqrt(5))
    out = []
    for i in range(n):
        zc = 1 - 2 * (i + 0.5) / n
        r = math.sqrt(1 - zc * zc)
        out.append(look_at(CENTRE + distance * np.array([r * math.cos(golden * i),
                                                         r * math.sin(golden * i), zc])))
    return out


def test_fusion_of_a_rendered_sphere_is_one_closed_piece_on_the_sphere():
    voxel = 0.02
    fusion = vdbrecon.Fusion(voxel, origin=CENTRE)
    for p in poses():
        assert fusion.integrate(render_sphere(p), K, p) > 1000
    assert fusion.frames == 20
    mesh = fusion.mesh()
    v = mesh.vertices.astype(np.float64) + np.asarray(mesh.origin)
    err = np.abs(np.linalg.norm(v - CENTRE, axis=1) - RADIUS)
    assert err.max() < 0.1 * voxel
    t = vdbrecon.mesh_topology(mesh)
    assert t.components == 1
    assert t.boundary_edges == 0 and t.nonmanifold_edges == 0
    vol = fusion.volume()
    assert vol.voxel_size == pytest.approx(voxel)


def test_opengl_poses_and_integer_depth_give_the_same_volume():
    ps = poses(6)
    a = vdbrecon.Fusion(0.03)
    b = vdbrecon.Fusion(0.03, depth_scale=1000)
    for p in ps:
        depth = render_sphere(p)
        a.integrate(depth, K, p)
        gl = p.copy()
        gl[:3, 1:3] *= -1
        b.integrate(np.round(depth * 1000).astype(np.uint16), (K[0, 0], K[1, 1], K[0, 2], K[1, 2]),
                    gl, convention="opengl")
    ma, mb = a.mesh(), b.mesh()
    assert abs(len(ma.faces) - len(mb.faces)) < 0.02 * len(ma.faces)
    ta, tb = vdbrecon.mesh_topology(ma), vdbrecon.mesh_topology(mb)
    assert tb.area == pytest.approx(ta.area, rel=0.01)


def test_bad_arguments_are_clear_errors():
    f = vdbrecon.Fusion(0.05, max_depth=10.0, depth_kind="planar")
    p = poses(1)[0]
    with pytest.raises(ValueError, match="rotation"):
        bad = p.copy()
        bad[:3, :3] *= 2
        f.integrate(render_sphere(p), K, bad)
    with pytest.raises(ValueError, match="4, 4"):
        f.integrate(render_sphere(p), K, np.eye(3))
    with pytest.raises(ValueError, match="H, W"):
        f.integrate(np.zeros(10, np.float32), K, p)
    with pytest.raises(TypeError):
        vdbrecon.Fusion(0.05, no_such_option=1)
    with pytest.raises(vdbrecon.NumericalError, match="usable pixel"):
        g = vdbrecon.Fusion(0.05)
        g.integrate(np.zeros((H, W), np.float32), K, p)
        g.mesh()


def test_tsdf_rule_by_keyword():
    fusion = vdbrecon.Fusion(0.02, rule="tsdf", truncation=3.0, origin=CENTRE)
    for p in poses(12):
        fusion.integrate(render_sphere(p), K, p)
    mesh = fusion.mesh()
    v = mesh.vertices.astype(np.float64) + np.asarray(mesh.origin)
    assert np.abs(np.linalg.norm(v - CENTRE, axis=1) - RADIUS).max() < 0.5 * 0.02
    assert vdbrecon.mesh_topology(mesh).components == 1
    with pytest.raises(ValueError, match="rule"):
        vdbrecon.Fusion(0.02, rule="voxels")


def paint(points):
    """A smooth colour field over space (0..1)."""
    p = (points - CENTRE) / RADIUS
    return np.clip(0.5 + 0.45 * np.stack([p[:, 0], p[:, 1], np.sin(2.5 * p[:, 2])], -1), 0, 1)


def colour_image(depth, pose, scale=1):
    """The colour each pixel of a (scale x larger) colour camera sees on the sphere."""
    h, w = depth.shape[0] * scale, depth.shape[1] * scale
    f, cx, cy = F * scale, (K[0, 2] + 0.5) * scale - 0.5, (K[1, 2] + 0.5) * scale - 0.5
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(u - cx) / f, (v - cy) / f, np.ones_like(u, dtype=float)], -1).reshape(-1, 3)
    d = rays @ pose[:3, :3].T
    o = pose[:3, 3] - CENTRE
    a, b, c = (d * d).sum(-1), 2 * (d @ o), o @ o - RADIUS ** 2
    t = (-b - np.sqrt(np.maximum(b * b - 4 * a * c, 0))) / (2 * a)
    return (paint(pose[:3, 3] + t[:, None] * d) * 255).round().astype(np.uint8).reshape(h, w, 3)


@pytest.mark.parametrize("rule", ["splat", "tsdf"])
def test_colour_images_give_vertex_colours(rule):
    fusion = vdbrecon.Fusion(0.02, origin=CENTRE, rule=rule)
    for i, p in enumerate(poses(12)):
        depth = render_sphere(p)
        if i % 2:  # a colour camera of twice the resolution, K scaled
            fusion.integrate(depth, K, p, color=colour_image(depth, p, 2))
        else:  # its own intrinsics, float colours
            fusion.integrate(depth, K, p, color=colour_image(depth, p).astype(np.float32) / 255,
                             color_K=K)
    mesh = fusion.mesh()
    assert mesh.colors is not None and len(mesh.colors) == len(mesh.vertices)
    v = mesh.vertices.astype(np.float64) + np.asarray(mesh.origin)
    err = np.abs(np.asarray(mesh.colors, dtype=np.float64) - paint(v))
    assert err.mean() < 0.01, err.mean()
    with pytest.raises(ValueError, match="H, W, 3"):
        fusion.integrate(render_sphere(poses(1)[0]), K, poses(1)[0], color=np.zeros((4, 4)))


@pytest.mark.parametrize("rule", ["splat", "tsdf"])
def test_lidar_scans_of_a_sphere(rule):
    rng = np.random.default_rng(5)
    fusion = vdbrecon.Fusion(0.03, origin=CENTRE, rule=rule)
    for axis in range(3):
        for sign in (1.0, -1.0):
            sensor = CENTRE.copy()
            sensor[axis] += 3.0 * sign
            # rays toward random points of the sphere's near side, hits by ray casting
            target = rng.normal(size=(20000, 3))
            target /= np.linalg.norm(target, axis=1)[:, None]
            d = CENTRE + RADIUS * target - sensor
            d /= np.linalg.norm(d, axis=1)[:, None]
            o = sensor - CENTRE
            b = d @ o
            disc = b * b - (o @ o - RADIUS ** 2)
            t = -b - np.sqrt(np.maximum(disc, 0))
            hits = (sensor + t[:, None] * d)[disc > 0]
            assert fusion.integrate_scan(hits, sensor) > 0.7 * len(hits)
    mesh = fusion.mesh()
    v = mesh.vertices.astype(np.float64) + np.asarray(mesh.origin)
    assert np.abs(np.linalg.norm(v - CENTRE, axis=1) - RADIUS).max() < 0.5 * 0.03
    assert vdbrecon.mesh_topology(mesh).components == 1
    with pytest.raises(ValueError, match="sensor"):
        fusion.integrate_scan(hits, (0, 0))
