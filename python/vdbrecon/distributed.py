"""The tiles of a tiled reconstruction as Dask distributed tasks.

    from dask.distributed import Client, LocalCluster
    import vdbrecon.distributed

    client = Client(LocalCluster(n_workers=2, threads_per_worker=1))  # or Client("tcp://scheduler:8786")
    vdbrecon.distributed.run("scan.ply", "scan.recon.ply", client=client, tile=256, voxel=0.01)

The client reads the input and runs the stages on the points (outliers, normals, voxel), writes
the oriented samples bucketed by tile into a job directory, and submits one task per tile.
Each worker reads the buckets around its tile from that directory itself, splats, closes and
meshes the tile, and returns its piece of the surface (bytes); the client keeps each piece in
a file of the job directory as it arrives, then welds the pieces in tile order and writes the
mesh. The file is the one `vdbrecon INPUT -o OUTPUT --tile N` writes
with the same options, byte for byte. A tile's task depends on nothing but the job's files, so
a worker that dies has its tiles recomputed elsewhere with the same result.

On a real cluster the job directory must be on a file system every worker mounts at the same
path (NFS, Lustre, a shared volume): give it as `workdir=`; by default it is a temporary
directory beside the output, removed afterwards. Workers need this package importable
(`vdbrecon` on their PYTHONPATH) and the input is read by the client only.

A given workdir is kept, and is the CLI's --job-dir: a client that was stopped (or the CLI
with --job-dir on the same directory) starts again from the preparation and the pieces that
are there, submitting only the missing tiles; a directory of another input or other options
is refused.
"""
import os as _os
import shutil as _shutil
import tempfile as _tempfile

from . import _vdbrecon as _v
from . import _RUN_NAMES, _fill_pipeline, _path, _voxel_option

__all__ = ["run"]


def _run_tile(workdir, index, options):
    """One tile's piece (runs on a worker)."""
    return _v.run_tile(workdir, index, _fill_pipeline(_RUN_NAMES, options, "distributed.run"))


def run(input, output=None, *, client, tile=-1, workdir=None, voxel=None, progress=None,
        **options):
    """Reconstructs `input` tile by tile on the Dask `client` and writes `output` (None:
    <input stem>.recon.ply beside the current directory, as vdbrecon.run()).

    tile: the tile edge in voxels, or -1 for the in-memory run's automatic guess from
    max_memory. workdir: the job directory (shared by the client and every worker; default a
    temporary directory beside the output, removed afterwards). progress: called with
    (tiles done, tiles) as pieces arrive. Every other keyword is an option of vdbrecon.run().
    Returns the RunResult of the written mesh (its result.timings are the client's stages).
    """
    import distributed  # noqa: F401  (Debian: python3-distributed)
    from distributed import as_completed

    if tile == 0:
        raise ValueError("distributed.run(): tile must be a tile edge in voxels or -1 (auto)")
    _voxel_option(voxel, options, "distributed.run")
    options = dict(options, tile=tile)
    o = _fill_pipeline(_RUN_NAMES, options, "distributed.run")
    input = _path(input, "input")
    output = "" if output is None else _path(output, "output")
    own = workdir is None
    if own:
        beside = _os.path.dirname(_os.path.abspath(output)) if output else _os.getcwd()
        workdir = _tempfile.mkdtemp(prefix=".vdbrecon-tiles-", dir=beside)
    workdir = _path(workdir, "workdir")
    try:
        job = _v.prepare_tiles(input, workdir, o)  # an earlier run's preparation is taken
        todo = [i for i in range(job.tiles) if not _v.has_tile_piece(workdir, i)]
        # Not pure: a second run with the same job directory and options reads new files, and
        # must not be handed the first run's pieces. A lost piece is recomputed either way.
        futures = client.map(_run_tile, [workdir] * len(todo), todo, [options] * len(todo),
                             pure=False)
        index = {f.key: i for f, i in zip(futures, todo)}
        # Each piece goes to the job directory as it arrives (atomically), so that the client
        # holds one piece at a time, not all of them (the weld reads them back one by one).
        done = job.tiles - len(todo)
        for future in as_completed(futures):
            _v.save_tile_piece(workdir, index[future.key], future.result())
            future.release()
            done += 1
            if progress is not None:
                progress(done, job.tiles)
        return _v.finish_tiles_in(input, output, workdir, o)
    finally:
        if own:
            _shutil.rmtree(workdir, ignore_errors=True)
