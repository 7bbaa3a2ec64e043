// Tile jobs (vdbrecon/tiles.h): the three steps vdbrecon.distributed runs, a tile's piece as
// bytes (what Dask moves between processes).
#include <fstream>
#include <iterator>
#include <string_view>

#include "bind.h"
#include "vdbrecon/error.h"
#include "vdbrecon/tiles.h"

namespace vdbrecon::python {

namespace {

/// A piece file's bytes; IoError naming it when it cannot be read.
std::string read_whole_file(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in.is_open()) throw IoError(path + ": cannot open the tile piece");
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) throw IoError(path + ": cannot read the tile piece");
    return bytes;
}

}  // namespace

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
        "save_tile_piece",
        [](const std::string& dir, std::size_t index, const py::bytes& piece) {
            const std::string bytes = piece;
            without_gil([&] { save_tile_piece(dir, index, bytes); });
        },
        py::arg("dir"), py::arg("index"), py::arg("piece"),
        "Keeps tile `index`'s piece in the job directory (atomically).");
    m.def(
        "has_tile_piece",
        [](const std::string& dir, std::size_t index) {
            return without_gil([&] { return has_tile_piece(dir, index); });
        },
        py::arg("dir"), py::arg("index"), "Whether the job directory holds tile `index`'s piece.");
    m.def(
        "finish_tiles_in",
        [](const std::string& input, const std::string& output, const std::string& dir,
           const PipelineOptions& options) {
            return without_gil([&] { return finish_tiles(input, output, dir, options); });
        },
        py::arg("input"), py::arg("output"), py::arg("dir"), py::arg("options"),
        "Welds the pieces kept in the job directory and writes the mesh as run() does.");
    m.def(
        "finish_tiles",
        [](const std::string& input, const std::string& output, const std::string& dir,
           const py::list& pieces, const PipelineOptions& options) {
            // Each piece is bytes, viewed where it is, or the path of a file holding them, read
            // when the join needs it: the pieces of a large job need not be in memory at once.
            const py::module_ os = py::module_::import("os");
            std::vector<std::string_view> bytes(pieces.size());
            std::vector<std::string> paths(pieces.size());
            for (std::size_t i = 0; i < pieces.size(); ++i) {
                const py::handle item = pieces[i];
                if (py::isinstance<py::bytes>(item)) {
                    char* data = nullptr;
                    Py_ssize_t size = 0;
                    PyBytes_AsStringAndSize(item.ptr(), &data, &size);
                    bytes[i] = std::string_view(data, std::size_t(size));
                } else {
                    paths[i] = os.attr("fspath")(item).cast<std::string>();
                }
            }
            const PieceSource source = [&](std::size_t i, std::string& buffer) {
                if (paths[i].empty()) return bytes[i];
                buffer = read_whole_file(paths[i]);
                return std::string_view(buffer);
            };
            return without_gil(
                [&] { return finish_tiles(input, output, dir, pieces.size(), source, options); });
        },
        py::arg("input"), py::arg("output"), py::arg("dir"), py::arg("pieces"),
        py::arg("options"),
        "Welds the pieces (in tile order; each bytes, or the path of a file holding them) and "
        "writes the mesh as run() does.");
}

}  // namespace vdbrecon::python
