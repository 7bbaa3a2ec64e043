// Writes the fuzzers' seed corpus: make_seeds DIR fills DIR/ply, DIR/xyz and DIR/obj with small
// files from the library's own writers (every PLY encoding, attributes, a far-away cloud stored
// in double) plus hand-made variants the writers never produce.
#include <sys/stat.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>

#include "vdbrecon/io.h"

using namespace vdbrecon;

namespace {

PointCloud cloud(std::size_t n, double offset) {
    PointCloud c;
    for (std::size_t i = 0; i < n; ++i) {
        const double t = 2.399963 * double(i), y = 1.0 - 2.0 * (double(i) + 0.5) / double(n);
        const double r = std::sqrt(1.0 - y * y);
        const Vec3f p{float(r * std::cos(t)), float(y), float(r * std::sin(t))};
        c.positions.push_back(p);
        c.normals.push_back(p);
        c.colors.push_back({float(i % 2), 0.5f, 1.0f});
        c.scales.push_back(0.1f);
        c.confidences.push_back(float(i % 3));
    }
    c.origin = {offset, -offset, 0.5 * offset};
    return c;
}

Mesh tetrahedron() {
    Mesh m;
    m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    m.normals = {{-1, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    m.colors = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
    m.faces = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    return m;
}

void text(const std::string& path, const std::string& content) {
    std::ofstream(path, std::ios::binary) << content;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: make_seeds DIR\n");
        return 2;
    }
    const std::string dir = argv[1];
    for (const char* sub : {"", "/ply", "/xyz", "/obj", "/pcd"}) ::mkdir((dir + sub).c_str(), 0755);

    const char* names[] = {"le", "be", "ascii"};
    const PlyEncoding encodings[] = {PlyEncoding::binary_little_endian,
                                     PlyEncoding::binary_big_endian, PlyEncoding::ascii};
    for (int k = 0; k < 3; ++k) {
        WriteOptions w;
        w.encoding = encodings[k];
        w.comments = {"seed"};
        write_points(dir + "/ply/cloud_" + names[k] + ".ply", cloud(12, 0.0), w);
        write_points(dir + "/ply/far_" + names[k] + ".ply", cloud(6, 1e7), w);
        write_mesh(dir + "/ply/mesh_" + names[k] + ".ply", tetrahedron(), w);
    }
    text(dir + "/ply/odd.ply",
         "ply\nformat ascii 1.0\ncomment odd order, lists, other elements\nobj_info x\n"
         "element camera 1\nproperty list uchar float params\nproperty int16 id\n"
         "element vertex 2\nproperty uchar red\nproperty float64 z\nproperty short flags\n"
         "property list uint8 int32 junk\nproperty double x\nproperty uint8 green\n"
         "property float32 nz\nproperty int8 tag\nproperty float ny\nproperty ushort quality\n"
         "property uint blue\nproperty float nx\nproperty float value\nproperty int y\n"
         "property float confidence\nelement face 1\nproperty list uchar int vertex_indices\n"
         "end_header\n3 0.5 1.5 2.5 -2\n255 -1.5 -3 2 7 8 2.25 0 1 -7 0 65535 255 0 0.5 -4 0.75\n"
         "0 3 12 0 -0.5 51 0 100 1 0 102 0 0.25 9 1\n4 0 1 1 0\n");
    text(dir + "/ply/crlf.ply",
         "ply\r\nformat ascii 1\r\nelement vertex 3\r\nproperty float x\r\nproperty float y\r\n"
         "property float z\r\nproperty float normal_x\r\nproperty float normal_y\r\n"
         "property float normal_z\r\nend_header\r\n0 0 0 0 0 1\r\n1 0 0 0 0 0\r\n"
         "nan 1 +1e3 0 0 -1\r\n");

    WriteOptions none;
    write_points(dir + "/xyz/normals.xyz", cloud(8, 0.0), none);
    write_points(dir + "/xyz/far.xyz", cloud(4, 1e7), none);
    text(dir + "/pcd/ascii.pcd",
         "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
         "WIDTH 2\nHEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\nDATA ascii\n0 0 1 4.2e-39\n"
         "nan nan nan 0\n1 0 1 0\n0 1 1.5 0\n");
    text(dir + "/pcd/binary.pcd",
         std::string("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\n"
                     "HEIGHT 1\nPOINTS 1\nDATA binary\n") + std::string(12, '\0'));
    text(dir + "/pcd/lzf.pcd",
         std::string("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\n"
                     "HEIGHT 1\nPOINTS 2\nDATA binary_compressed\n") +
             std::string("\x05\x00\x00\x00\x18\x00\x00\x00\x00\x00\xe0\x0e\x00", 13));
    text(dir + "/xyz/plain.xyz", "# x y z\n1 2 3\n4,5,6\n\n7\t8 9\n// c\n+1e-3 -2E+2 nan\n");
    text(dir + "/xyz/intensity.xyz", "0 0 0 10\n1 1 1 20\n2 2 2 inf\n");
    text(dir + "/xyz/scan.pts", "3\n1 2 3 10 255 0 0\n4 5 6 10 0 255 0\n7 8 9 -5 0 0 255\n");

    write_mesh(dir + "/obj/mesh.obj", tetrahedron(), none);
    text(dir + "/obj/mixed.obj",
         "# mixed\no thing\nv 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nv 1 1 0\nvt 0 0\n"
         "vn 0 0 1\nvn 0 0 -1\ng part\nf 1/1/1 2/1/1 3/1/1\nf -1//2 -2//2 -3//2 -4//2\n"
         "f 1 2 4\ns off\nusemtl m\n");
    text(dir + "/obj/points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\n");
    return 0;
}
