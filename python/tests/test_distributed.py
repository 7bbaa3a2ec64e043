"""vdbrecon.distributed: the tiles of a tiled run as Dask tasks on a 2-worker LocalCluster
(processes) write the bytes the CLI's --tile run writes, also when a worker dies mid-run."""
import logging
import os
import signal
import subprocess

import pytest

import vdbrecon
from conftest import SOURCE_DIR

distributed = pytest.importorskip(
    "distributed", reason="SKIPPED: Dask distributed is not installed (Debian: python3-distributed, "
    "which scripts/setup.sh installs)")
import vdbrecon.distributed  # noqa: E402


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.ERROR)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


def cli_tiled(cli, src, out, *args):
    r = subprocess.run([cli, str(src), "-o", str(out), "-q", *args], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return out.read_bytes()


SRC = SOURCE_DIR / "data" / "bunny_sample.ply"


def test_the_cli_bytes_from_tasks(client, cli, tmp_path):
    expected = cli_tiled(cli, SRC, tmp_path / "cli.ply", "--tile", "32", "--mesher", "dc")
    r = vdbrecon.distributed.run(SRC, tmp_path / "dask.ply", client=client, tile=32, method="dc")
    assert (tmp_path / "dask.ply").read_bytes() == expected
    assert r.result.tile == 32 and r.result.tiles > 8 and r.vdb_path == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cli.ply", "dask.ply"]  # job removed


def test_streamed_jobs_give_the_same_bytes(client, cli, tmp_path):
    # The client streams the file (its points never held whole) into the job; the tiles, and
    # the bytes, are those of the run that holds the points.
    expected = cli_tiled(cli, SRC, tmp_path / "cli.ply", "--tile", "32", "--stream", "off")
    r = vdbrecon.distributed.run(SRC, tmp_path / "dask.ply", client=client, tile=32,
                                 stream="on")
    assert (tmp_path / "dask.ply").read_bytes() == expected
    assert r.result.tiles > 8
    assert cli_tiled(cli, SRC, tmp_path / "on.ply", "--tile", "32", "--stream", "on") == expected


def test_a_lidar_tile_without_normals_streams_with_up(client, cli, shared_data, tmp_path):
    # Normals estimated and turned up, each point on its own: the client streams the LAS file
    # too, and the bytes are those of the run that reads it whole.
    las = shared_data / "pdal_autzen" / "autzen_trim.las"
    args = ("--voxel", "4.4", "--tile", "32", "--up", "0,0,1")
    expected = cli_tiled(cli, las, tmp_path / "cli.ply", *args, "--stream", "off")
    r = vdbrecon.run(las, tmp_path / "run.ply", tile=32, voxel=4.4, up=(0, 0, 1), stream="on")
    assert (tmp_path / "run.ply").read_bytes() == expected
    assert r.result.stream_units >= 8 and r.result.normals.estimated > 100000
    assert r.result.normals.oriented_to_viewpoint
    vdbrecon.distributed.run(las, tmp_path / "dask.ply", client=client, tile=32, voxel=4.4,
                             up=(0, 0, 1), stream="on")
    assert (tmp_path / "dask.ply").read_bytes() == expected


def test_a_worker_killed_mid_run_changes_nothing(client, cli, tmp_path):
    expected = cli_tiled(cli, SRC, tmp_path / "cli.ply", "--tile", "48", "--close", "2")
    killed = []

    pids = client.run(os.getpid)  # worker address -> process id

    def kill_one_worker(done, tiles):
        if done == 2 and not killed:  # tiles are still running or waiting
            worker = sorted(pids)[0]
            os.kill(pids[worker], signal.SIGKILL)
            killed.append(worker)

    workdir = tmp_path / "job"
    workdir.mkdir()
    r = vdbrecon.distributed.run(SRC, tmp_path / "dask.ply", client=client, tile=48,
                                 hole_radius=2, workdir=workdir, progress=kill_one_worker)
    assert killed
    assert (tmp_path / "dask.ply").read_bytes() == expected
    assert r.result.tiles > 8
    assert (workdir / "plan.bin").exists()  # a given workdir is kept


def test_bad_job_directory_and_options(client, tmp_path):
    with pytest.raises(ValueError):
        vdbrecon.distributed.run(SRC, tmp_path / "x.ply", client=client, tile=0)
    with pytest.raises(vdbrecon.IoError, match="plan.bin"):
        vdbrecon._vdbrecon.run_tile(str(tmp_path), 0, vdbrecon.PipelineOptions())
    assert not (tmp_path / "x.ply").exists()


def test_pieces_as_bytes_or_files_weld_to_the_cli_bytes(cli, tmp_path):
    """The three library steps in this process, each piece handed over as bytes or as the
    path of a file holding them (as vdbrecon.distributed does): the CLI's --tile bytes."""
    expected = cli_tiled(cli, SRC, tmp_path / "cli.ply", "--tile", "32")
    o = vdbrecon.PipelineOptions()
    o.tile = 32
    job_dir = tmp_path / "job"
    job_dir.mkdir()
    job = vdbrecon._vdbrecon.prepare_tiles(str(SRC), str(job_dir), o)
    assert job.tiles > 8
    pieces = []
    for i in range(job.tiles):
        piece = vdbrecon._vdbrecon.run_tile(str(job_dir), i, o)
        if i % 2:
            path = tmp_path / ("piece-%d.bin" % i)
            path.write_bytes(piece)
            pieces.append(path)
        else:
            pieces.append(piece)
    vdbrecon._vdbrecon.finish_tiles(str(SRC), str(tmp_path / "lib.ply"), str(job_dir), pieces, o)
    assert (tmp_path / "lib.ply").read_bytes() == expected
    pieces[1] = tmp_path / "missing.bin"
    with pytest.raises(vdbrecon.IoError, match="missing.bin"):
        vdbrecon._vdbrecon.finish_tiles(str(SRC), str(tmp_path / "bad.ply"), str(job_dir),
                                        pieces, o)
    assert not (tmp_path / "bad.ply").exists()


def test_a_stopped_client_resumes_from_the_pieces_in_workdir(client, cli, tmp_path):
    """The workdir is the CLI's --job-dir: a client that stopped after some tiles (here: its
    progress callback raised) submits only the missing ones when run again; the CLI on the same
    directory resumes too; a changed option is refused."""
    expected = cli_tiled(cli, SRC, tmp_path / "cli.ply", "--tile", "32")
    workdir = tmp_path / "job"

    class Stop(Exception):
        pass

    def stop_after_3(done, tiles):
        if done == 3:
            raise Stop()

    with pytest.raises(Stop):
        vdbrecon.distributed.run(SRC, tmp_path / "a.ply", client=client, tile=32,
                                 workdir=workdir, progress=stop_after_3)
    kept = len(list(workdir.glob("piece-*.bin")))
    assert kept >= 3
    seen = []
    r = vdbrecon.distributed.run(SRC, tmp_path / "a.ply", client=client, tile=32,
                                 workdir=workdir, progress=lambda d, t: seen.append(d))
    assert (tmp_path / "a.ply").read_bytes() == expected
    assert seen and seen[0] == kept + 1 and seen[-1] == r.result.tiles
    assert cli_tiled(cli, SRC, tmp_path / "b.ply", "--tile", "32", "--job-dir", str(workdir)) == expected
    with pytest.raises(ValueError, match="another run's"):
        vdbrecon.distributed.run(SRC, tmp_path / "c.ply", client=client, tile=48, workdir=workdir)
    assert vdbrecon.run(SRC, tmp_path / "d.ply", tile=32, job_dir=workdir).result.tiles == r.result.tiles
    assert (tmp_path / "d.ply").read_bytes() == expected
