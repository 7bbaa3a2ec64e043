"""vdbrecon.decimate and reconstruct(ratio=...): QEM decimation keeps a closed sphere closed."""
import numpy as np
import pytest

import vdbrecon
from conftest import sphere


def test_decimate_a_reconstructed_sphere():
    p, n = sphere(20000)
    mesh = vdbrecon.reconstruct(p, n, voxel=0.05)
    r = vdbrecon.decimate(mesh, ratio=0.2)
    assert r.faces_after <= int(np.ceil(0.2 * len(mesh.faces))) + 1
    t = vdbrecon.mesh_topology(r.mesh)
    assert t.watertight() and t.components == 1 and t.euler == 2
    radius = np.linalg.norm(r.mesh.vertices.astype(np.float64) + r.mesh.origin, axis=1)
    assert np.abs(radius - 1.0).max() < 0.02
    same = vdbrecon.reconstruct(p, n, voxel=0.05, ratio=0.2)
    assert len(same.faces) == r.faces_after
    with pytest.raises(ValueError, match="ratio"):
        vdbrecon.decimate(mesh, ratio=0.0)
