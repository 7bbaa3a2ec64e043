// Tile jobs (vdbrecon/tiles.h): the three steps vdbrecon.distributed runs, a tile's piece as
// bytes (what Dask moves between processes).
#include "bind.h"
#include "vdbrecon/tiles.h"

namespace vdbrecon::python {

void bind_tiles(py::module_& m) {
    py::class_<TileJob>(m, "TileJob", "What prepare_tiles() did.")
        .def_readonly("dir", &TileJob::dir)
        .def_readonly("tiles", &TileJob::tiles, "Tiles to run: run_tile(dir, 0 .. tiles - 1).")
        .def_readonly("tile", &TileJob::tile, "The tile edge, voxels.")
        .def_readonly("voxel_size", &TileJob::voxel_size, "The voxel used, world units.")
        .def_readonly("result", &TileJob::result,
                      "PipelineResult of the stages on the points (no mesh).")
        .def_readonly("read", &TileJob::read, "ReadResult (counts; no cloud).");
    m.def(
        "prepare_tiles",
        [](const std::string& input, const std::string& dir, const PipelineOptions& options) {
            return without_gil([&] { return prepare_tiles(input, dir, options); });
        },
        py::arg("input"), py::arg("dir"), py::arg("options"),
        "Reads `input`, runs the stages on the points and writes a tile job into `dir`.");
    m.def(
        "run_tile",
        [](const std::string& dir, std::size_t index, const PipelineOptions& options) {
            std::string piece =
                without_gil([&] { return run_tile(dir, index, options); });
            return py::bytes(piece);
        },
        py::arg("dir"), py::arg("index"), py::arg("options"),
        "Tile `index`'s piece of the surface, as bytes.");
    m.def(
        "finish_tiles",
        [](const std::string& input, const std::string& output, const std::string& dir,
           const std::vector<py::bytes>& pieces, const PipelineOptions& options) {
            std::vector<std::string> p;
            p.reserve(pieces.size());
            for (const py::bytes& b : pieces) p.push_back(std::string(b));
            return without_gil([&] { return finish_tiles(input, output, dir, p, options); });
        },
        py::arg("input"), py::arg("output"), py::arg("dir"), py::arg("pieces"),
        py::arg("options"), "Welds the pieces (in tile order) and writes the mesh as run() does.");
}

}  // namespace vdbrecon::python
