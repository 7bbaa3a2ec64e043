"""Shared fixtures: analytic point samples, the CLI, the shared scan corpus.

Run from the build tree (ctest does this):
    PYTHONPATH=<build>/python VDBRECON_CLI=<build>/vdbrecon /usr/bin/python3 -m pytest python/tests
"""
import math
import os
import pathlib
import shutil

import numpy as np
import pytest

SOURCE_DIR = pathlib.Path(__file__).resolve().parents[2]


def sphere(n, radius=1.0, centre=(0.0, 0.0, 0.0)):
    """n points on a sphere (Fibonacci spiral: nearly uniform, deterministic) and their outward
    unit normals, both (n, 3) float32 -- the same sampler as tests/support.h."""
    i = np.arange(n, dtype=np.float64)
    y = 1.0 - 2.0 * (i + 0.5) / n
    r = np.sqrt(1.0 - y * y)
    t = math.pi * (3.0 - math.sqrt(5.0)) * i
    normals = np.stack([r * np.cos(t), y, r * np.sin(t)], axis=1)
    points = np.asarray(centre) + radius * normals
    return points.astype(np.float32), normals.astype(np.float32)


@pytest.fixture(scope="session")
def sphere_cloud():
    return sphere(20000, 1.0)


@pytest.fixture(scope="session")
def sphere_result(sphere_cloud):
    import vdbrecon
    points, normals = sphere_cloud
    return vdbrecon.reconstruct(points, normals, voxel=0.04, return_result=True)


@pytest.fixture(scope="session")
def cli():
    path = os.environ.get("VDBRECON_CLI") or shutil.which("vdbrecon")
    if not path or not os.path.exists(path):
        pytest.skip("the vdbrecon CLI was not found (set VDBRECON_CLI=<build>/vdbrecon)")
    return path


@pytest.fixture(scope="session")
def shared_data():
    default = SOURCE_DIR.parent / "shared" / "data"
    path = pathlib.Path(os.environ.get("VDBRECON_SHARED_DATA", default))
    if not path.is_dir():
        pytest.skip(f"SKIPPED: the shared scan corpus {path} is absent (present on CI only)")
    return path
