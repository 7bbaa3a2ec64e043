// Writes the fuzzers' seed corpus: make_seeds DIR fills DIR/<target> for every target of
// fuzz/CMakeLists.txt with small files from the library's own writers (every PLY encoding,
// attributes, a far-away cloud stored in double; depth images as EXR and PNG, colour images as
// PNG and JPEG) plus hand-made variants the writers never produce: other LAS versions and point
// formats, PNG colour types, EXR compressions, channel names and tiles, progressive and
// arithmetic-coded JPEG, transforms.json dialects and one folder of each dataset layout.
#include <sys/stat.h>

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfMultiPartOutputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfOutputPart.h>
#include <OpenEXR/ImfPartType.h>
#include <OpenEXR/ImfPreviewImage.h>
#include <OpenEXR/ImfStringVectorAttribute.h>
#include <OpenEXR/ImfTiledOutputFile.h>
#include <OpenEXR/ImfTiledOutputPart.h>
#include <zlib.h>

#include <cmath>
#include <cstdio>  // before jpeglib.h, which uses FILE and size_t
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include <jpeglib.h>

#include "vdbrecon/io.h"
#include "vdbrecon/scene.h"

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

void seed_points(const std::string& dir) {
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
}

// ---------------------------------------------------------------------------------------------
// LAS

template <typename T>
void put(std::string& b, std::size_t at, T v) {
    std::memcpy(&b[at], &v, sizeof(T));
}

/// A LAS 1.minor file of `n` points of point format `format`, records 2 bytes longer than the
/// format needs (extra bytes), with 8-bit (`rgb` 255) or 16-bit colours where it has them.
std::string las(int minor, int format, std::uint32_t n, std::uint16_t rgb = 65535) {
    static const std::size_t sizes[11] = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
    const std::size_t rgb_at = format == 2                                  ? 20
                               : format == 3 || format == 5                 ? 28
                               : format == 7 || format == 8 || format == 10 ? 30
                                                                            : 0;
    const std::uint16_t header = minor >= 4 ? 375 : 227, record = std::uint16_t(sizes[format] + 2);
    std::string b(header, '\0');
    std::memcpy(&b[0], "LASF", 4);
    b[24] = 1;
    b[25] = char(minor);
    put<std::uint16_t>(b, 94, header);
    put<std::uint32_t>(b, 96, header);
    b[104] = char(format);
    put<std::uint16_t>(b, 105, record);
    put<std::uint32_t>(b, 107, format >= 6 ? 0 : n);  // 1.4 formats count in the 64-bit field
    for (int a = 0; a < 3; ++a) {
        put<double>(b, 131 + 8 * std::size_t(a), 0.01);
        put<double>(b, 155 + 8 * std::size_t(a), 1000.0 * a);
    }
    if (minor >= 4) put<std::uint64_t>(b, 247, n);
    for (std::uint32_t i = 0; i < n; ++i) {
        std::string r(record, '\0');
        put<std::int32_t>(r, 0, std::int32_t(100 * i));
        put<std::int32_t>(r, 4, std::int32_t(-50 * i));
        put<std::int32_t>(r, 8, std::int32_t(7 * i));
        put<std::uint16_t>(r, 12, std::uint16_t(300 + i));
        r[14] = char(format >= 6 ? 0x21 : 0x11);
        r[format >= 6 ? 16 : 15] = char(2 + i % 5);
        for (std::size_t c = 0; c < 3 && rgb_at; ++c) {
            put<std::uint16_t>(r, rgb_at + 2 * c, std::uint16_t((i * 97 + c * 31) % (rgb + 1u)));
        }
        b += r;
    }
    return b;
}

void seed_las(const std::string& dir) {
    text(dir + "/v12_f0.las", las(2, 0, 3));
    text(dir + "/v12_f2_rgb8.las", las(2, 2, 4, 255));
    text(dir + "/v13_f3.las", las(3, 3, 3));
    text(dir + "/v14_f6.las", las(4, 6, 3));
    text(dir + "/v14_f7.las", las(4, 7, 2));
    text(dir + "/v14_f10.las", las(4, 10, 2));
    std::string laz = las(2, 1, 1);
    laz[104] = char(0x81);  // LASzip's compression bit
    text(dir + "/laz.las", laz);
}

// ---------------------------------------------------------------------------------------------
// PNG (depth and colour)

void put_u32(std::string& s, std::uint32_t v) {
    for (int sh = 24; sh >= 0; sh -= 8) s.push_back(char((v >> sh) & 0xff));
}

void chunk(std::string& png, const char* type, const std::string& data) {
    put_u32(png, std::uint32_t(data.size()));
    const std::string body = std::string(type, 4) + data;
    png += body;
    put_u32(png, std::uint32_t(
                     crc32(0L, reinterpret_cast<const Bytef*>(body.data()), uInt(body.size()))));
}

/// A PNG file of w x h pixels from its raw (filtered) rows, with `extra` chunks (type + data)
/// before the image data.
std::string png(std::uint32_t w, std::uint32_t h, int bits, int type, const std::string& raw,
                bool interlaced = false, const std::vector<std::string>& extra = {}) {
    std::string out("\x89PNG\r\n\x1a\n", 8), ihdr;
    put_u32(ihdr, w);
    put_u32(ihdr, h);
    ihdr += std::string{char(bits), char(type), 0, 0, char(interlaced)};
    chunk(out, "IHDR", ihdr);
    for (const std::string& e : extra) chunk(out, e.substr(0, 4).c_str(), e.substr(4));
    uLongf n = compressBound(uLong(raw.size()));
    std::string z(n, '\0');
    compress2(reinterpret_cast<Bytef*>(&z[0]), &n, reinterpret_cast<const Bytef*>(raw.data()),
              uLong(raw.size()), 9);
    z.resize(n);
    chunk(out, "IDAT", z);
    chunk(out, "IEND", "");
    return out;
}

/// Raw rows of w x h pixels of `bytes` bytes each, filter type `filter` (0..4), values a ramp.
std::string rows(int w, int h, int bytes, int filter) {
    std::string raw;
    for (int y = 0; y < h; ++y) {
        raw.push_back(char(filter));
        for (int i = 0; i < w * bytes; ++i) raw.push_back(char((y * 37 + i * 11) & 0xff));
    }
    return raw;
}

void seed_images(const std::string& dir) {
    DepthImage d{7, 5, {}};
    for (int i = 0; i < 35; ++i) d.depth.push_back(i % 6 == 0 ? 0.0f : 0.5f + 0.0731f * float(i));
    write_depth_image(dir + "/depth_png/d16.png", d, 5000.0);
    write_depth_image(dir + "/depth_exr/z.exr", d);
    const std::string dp = dir + "/depth_png/";
    text(dp + "gray8.png", png(4, 3, 8, 0, rows(4, 3, 1, 1)));
    text(dp + "gray16_paeth.png", png(3, 4, 16, 0, rows(3, 4, 2, 4)));
    text(dp + "gray16_interlaced.png", png(1, 1, 16, 0, rows(1, 1, 2, 0), true));
    text(dp + "gray16_text.png",
         png(2, 2, 16, 0, rows(2, 2, 2, 2), false, {std::string("tEXtdepth\0mm", 12)}));
    ColorImage c{6, 4, {}};
    for (int i = 0; i < 24; ++i) c.rgb.push_back({float(i % 6) / 5.0f, float(i / 6) / 3.0f, 0.5f});
    write_color_image(dir + "/color_png/rgb8.png", c);
    write_color_image(dir + "/color_jpg/rgb_q95.jpg", c);
    const std::string cp = dir + "/color_png/";
    text(cp + "gray1.png", png(9, 2, 1, 0, rows(2, 2, 1, 0)));
    text(cp + "gray_alpha8.png", png(3, 2, 8, 4, rows(3, 2, 2, 3)));
    text(cp + "rgba8.png", png(2, 3, 8, 6, rows(2, 3, 4, 1)));
    text(cp + "rgb16.png", png(2, 2, 16, 2, rows(2, 2, 6, 2)));
    text(cp + "palette2.png",
         png(5, 3, 2, 3, rows(2, 3, 1, 0), false,
             {std::string("PLTE\xff\x00\x00\x00\xff\x00\x00\x00\xff\x80\x80\x80", 16),
              std::string("tRNS\xff\x80", 6)}));
    text(cp + "gray16_interlaced.png", png(1, 1, 16, 0, rows(1, 1, 2, 0), true));
}

// ---------------------------------------------------------------------------------------------
// EXR depth

/// An EXR file of w x h pixels, one channel `channel` of `type`, with `compression`; scan lines
/// or (tile > 0) tiles of tile x tile pixels; its data window starting at (x0, y0).
void exr(const std::string& path, const char* channel, Imf::PixelType type,
         Imf::Compression compression, int tile = 0, int x0 = 0, int y0 = 0) {
    const int w = 6, h = 5;
    Imf::Header header(w, h);
    header.dataWindow() = Imath::Box2i(Imath::V2i(x0, y0), Imath::V2i(x0 + w - 1, y0 + h - 1));
    header.compression() = compression;
    header.channels().insert(channel, Imf::Channel(type));
    std::vector<float> z(std::size_t(w * h));
    for (std::size_t i = 0; i < z.size(); ++i) z[i] = i % 7 == 0 ? 1e10f : 0.25f * float(i);
    std::vector<unsigned> u(z.size());
    std::vector<half> f16(z.size());
    for (std::size_t i = 0; i < u.size(); ++i) u[i] = unsigned(i * 3), f16[i] = half(z[i]);
    void* pixels = type == Imf::UINT   ? static_cast<void*>(u.data())
                   : type == Imf::HALF ? static_cast<void*>(f16.data())
                                       : static_cast<void*>(z.data());
    Imf::FrameBuffer fb;  // of the file's type: OpenEXR converts types when reading only
    fb.insert(channel, Imf::Slice::Make(type, pixels, header.dataWindow()));
    if (tile > 0) {
        header.setTileDescription(Imf::TileDescription(unsigned(tile), unsigned(tile)));
        Imf::TiledOutputFile out(path.c_str(), header);
        out.setFrameBuffer(fb);
        out.writeTiles(0, out.numXTiles() - 1, 0, out.numYTiles() - 1);
    } else {
        Imf::OutputFile out(path.c_str(), header);
        out.setFrameBuffer(fb);
        out.writePixels(h);
    }
}

/// A two-part EXR file (depth scan lines, then a tiled part), the first with a preview image
/// and a string vector attribute.
void exr_extras(const std::string& path) {
    const int w = 4, h = 3;
    std::vector<float> z(std::size_t(w * h), 1.5f);
    std::vector<Imf::Header> headers(2, Imf::Header(w, h));
    for (std::size_t i = 0; i < 2; ++i) {
        headers[i].setName(i == 0 ? "depth" : "tiles");
        headers[i].channels().insert("Z", Imf::Channel(Imf::FLOAT));
    }
    headers[0].setType(Imf::SCANLINEIMAGE);
    headers[0].setPreviewImage(Imf::PreviewImage(2, 1));
    headers[0].insert("notes", Imf::StringVectorAttribute({"seed", "depth in metres"}));
    headers[1].setType(Imf::TILEDIMAGE);
    headers[1].setTileDescription(Imf::TileDescription(2, 2));
    Imf::MultiPartOutputFile out(path.c_str(), headers.data(), 2);
    Imf::FrameBuffer fb;
    fb.insert("Z", Imf::Slice::Make(Imf::FLOAT, z.data(), headers[0].dataWindow()));
    Imf::OutputPart first(out, 0);
    first.setFrameBuffer(fb);
    first.writePixels(h);
    Imf::TiledOutputPart second(out, 1);
    second.setFrameBuffer(fb);
    second.writeTiles(0, second.numXTiles() - 1, 0, second.numYTiles() - 1);
}

void seed_exr(const std::string& dir) {
    const std::pair<const char*, Imf::Compression> kinds[] = {
        {"none", Imf::NO_COMPRESSION},   {"rle", Imf::RLE_COMPRESSION},
        {"zips", Imf::ZIPS_COMPRESSION}, {"zip", Imf::ZIP_COMPRESSION},
        {"piz", Imf::PIZ_COMPRESSION},   {"pxr24", Imf::PXR24_COMPRESSION},
        {"b44", Imf::B44_COMPRESSION},   {"b44a", Imf::B44A_COMPRESSION},
        {"dwaa", Imf::DWAA_COMPRESSION}, {"dwab", Imf::DWAB_COMPRESSION}};
    for (const auto& [name, c] : kinds) {
        exr(dir + "/half_" + name + ".exr", "depth", Imf::HALF, c);
        exr(dir + "/float_" + name + ".exr", "Z", Imf::FLOAT, c);
    }
    exr(dir + "/uint_r.exr", "R", Imf::UINT, Imf::ZIP_COMPRESSION);
    exr(dir + "/layer.exr", "ViewLayer.Depth.Z", Imf::FLOAT, Imf::RLE_COMPRESSION);
    exr(dir + "/no_depth.exr", "G", Imf::HALF, Imf::NO_COMPRESSION);
    exr(dir + "/window.exr", "Y", Imf::HALF, Imf::ZIPS_COMPRESSION, 0, -3, 7);
    exr(dir + "/tiled.exr", "Z", Imf::FLOAT, Imf::ZIP_COMPRESSION, 4);
    exr(dir + "/tiled_piz.exr", "depth", Imf::HALF, Imf::PIZ_COMPRESSION, 2, 1, 1);
    exr_extras(dir + "/multipart_preview.exr");
}

// ---------------------------------------------------------------------------------------------
// JPEG colour

/// A JPEG of 16 x 12 pixels with `components` (1 grey, 3 RGB), progressive and/or arithmetic
/// coded, with 2x2-subsampled chroma when `subsampled`, a restart marker every row of blocks
/// when `restarts`.
void jpeg(const std::string& path, int components, bool progressive, bool arithmetic,
          bool subsampled, bool restarts) {
    const int w = 16, h = 12;
    std::vector<std::uint8_t> pixels(std::size_t(w * h * components));
    for (std::size_t i = 0; i < pixels.size(); ++i) pixels[i] = std::uint8_t((i * 29) & 0xff);
    std::FILE* f = std::fopen(path.c_str(), "wb");
    if (!f) return;
    jpeg_compress_struct info{};
    jpeg_error_mgr err{};
    info.err = jpeg_std_error(&err);
    jpeg_create_compress(&info);
    jpeg_stdio_dest(&info, f);
    info.image_width = w;
    info.image_height = h;
    info.input_components = components;
    info.in_color_space = components == 1 ? JCS_GRAYSCALE : JCS_RGB;
    jpeg_set_defaults(&info);
    jpeg_set_quality(&info, 80, TRUE);
    if (progressive) jpeg_simple_progression(&info);
    info.arith_code = arithmetic ? TRUE : FALSE;
    if (components == 3 && !subsampled) {
        info.comp_info[0].h_samp_factor = info.comp_info[0].v_samp_factor = 1;
    }
    if (restarts) info.restart_in_rows = 1;
    jpeg_start_compress(&info, TRUE);
    while (info.next_scanline < info.image_height) {
        JSAMPROW row =
            pixels.data() + std::size_t(info.next_scanline) * std::size_t(w * components);
        jpeg_write_scanlines(&info, &row, 1);
    }
    jpeg_finish_compress(&info);
    jpeg_destroy_compress(&info);
    std::fclose(f);
}

void seed_jpeg(const std::string& dir) {
    jpeg(dir + "/grey.jpg", 1, false, false, false, false);
    jpeg(dir + "/rgb_420.jpg", 3, false, false, true, false);
    jpeg(dir + "/rgb_444_restarts.jpg", 3, false, false, false, true);
    jpeg(dir + "/progressive.jpg", 3, true, false, true, false);
    jpeg(dir + "/arithmetic.jpg", 3, false, true, true, false);
    jpeg(dir + "/progressive_arithmetic_grey.jpg", 1, true, true, false, false);
}

// ---------------------------------------------------------------------------------------------
// Scenes

/// `json` with %I and %T replaced by an identity and a turned transform_matrix.
std::string with_poses(std::string json) {
    const std::pair<const char*, const char*> poses[] = {
        {"%I", "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]"},
        {"%T", "[[0, 0, 1, 2.5], [0, 1, 0, -1], [-1, 0, 0, 0.25], [0, 0, 0, 1]]"}};
    for (const auto& [key, matrix] : poses) {
        for (std::size_t at = json.find(key); at != std::string::npos; at = json.find(key)) {
            json.replace(at, 2, matrix);
        }
    }
    return json;
}

void seed_transforms(const std::string& dir) {
    text(dir + "/blender.json", with_poses(R"({"camera_angle_x": 0.6911112070083618, "frames": [
  {"file_path": "./r_0", "rotation": 0.01, "transform_matrix": %I},
  {"file_path": "r_1", "transform_matrix": %T}]}
)"));
    text(dir + "/nerf_synthetic.json",
         with_poses(R"({"camera_angle_x": 0.6911112070083618, "w": 800, "h": 800, "frames": [
  {"file_path": "./r_0", "transform_matrix": %T}]}
)"));
    text(dir + "/ngp.json",
         with_poses(R"({"fl_x": 500.5, "fl_y": 499.5, "cx": 320, "cy": 240, "w": 640, "h": 480,
 "integer_depth_scale": 0.00025, "aabb_scale": 4, "frames": [
  {"file_path": "r_0.png", "depth_file_path": "d.exr", "transform_matrix": %I},
  {"file_path": "x.jpg", "depth_path": "d", "fl_x": 400, "w": 320, "h": 240,
   "transform_matrix": %T}]}
)"));
    text(dir + "/angles.json",
         with_poses(R"({"camera_angle_x": 1.2, "camera_angle_y": 0.9, "w": 64, "h": 48,
 "depth_scale": 0.001, "cx": null, "frames": [{"file_path": "r_1", "camera_angle_x": 0.5,
 "transform_matrix": %T}]}
)"));
}

/// A scene input: its files joined as the scene targets split them (fuzz_scene.h).
std::string folder(const std::vector<std::pair<std::string, std::string>>& files) {
    std::string out;
    for (const auto& [name, bytes] : files) {
        out += (out.empty() ? "=== " : "\n=== ") + name + "\n" + bytes;
    }
    return out;
}

const std::string kPose44 = "1 0 0 0.5\n0 1 0 -0.25\n0 0 1 2\n0 0 0 1\n";
const std::string kPose34 = "1 0 0 0.5 0 1 0 -0.25 0 0 1 2\n";

/// Two KITTI points (float32 x y z intensity), one of them NaN.
std::string velodyne() {
    const float v[8] = {1.5f, -2.0f, 0.25f, 0.5f, NAN, 1.0f, 2.0f, 0.0f};
    return std::string(reinterpret_cast<const char*>(v), sizeof v);
}

void seed_layouts(const std::string& dir) {
    text(dir + "/tum.scene", folder({{"depth.txt",
                                      "# depth maps\n1305031102.160407 depth/1.png\n"
                                      "1305031102.194330 depth/2.png\n"},
                                     {"groundtruth.txt",
                                      "# timestamp tx ty tz qx qy qz qw\n"
                                      "1305031102.1600 1.3 0.6 1.6 0.5 0.5 -0.5 0.5\n"
                                      "1305031102.1900 1.3 0.6 1.6 0 0 0 1\n"},
                                     {"rgb.txt", "1305031102.175304 rgb/1.png\n"},
                                     {"depth/1.png", ""},
                                     {"rgb/1.png", ""}}));
    text(dir + "/7scenes.scene",
         folder({{"camera-intrinsics.txt", "585 0 320\n0 585 240\n0 0 1\n"},
                 {"frame-000000.depth.png", ""},
                 {"frame-000000.pose.txt", kPose44},
                 {"frame-000000.color.png", ""},
                 {"frame-000001.depth.png", ""},
                 {"frame-000001.pose.txt", "inf inf inf inf\n" + kPose44.substr(10)}}));
    text(dir + "/redwood.scene",
         folder({{"trajectory.log", "0 0 1\n" + kPose44 + "1 1 2\n" + kPose44},
                 {"camera_intrinsic.json",
                  "{\"width\": 640, \"height\": 480, \"intrinsic_matrix\": "
                  "[525, 0, 0, 0, 525, 0, 319.5, 239.5, 1]}"},
                 {"depth/000000.png", ""},
                 {"depth/000001.png", ""},
                 {"color/000000.jpg", ""},
                 {"color/000001.jpg", ""}}));
    text(
        dir + "/scannet.scene",
        folder({{"intrinsic/intrinsic_depth.txt",
                 "577.6 0 319.5 0\n0 578.7 239.5 0\n0 0 1 0\n0 0 0 1\n"},
                {"intrinsic/intrinsic_color.txt", "1170 0 647 0\n0 1170 483 0\n0 0 1 0\n0 0 0 1\n"},
                {"depth/0.png", ""},
                {"pose/0.txt", kPose44},
                {"color/0.jpg", ""},
                {"depth/1.png", ""},
                {"pose/1.txt",
                 "-inf -inf -inf -inf\n-inf -inf -inf -inf\n"
                 "-inf -inf -inf -inf\n-inf -inf -inf -inf\n"}}));
    text(dir + "/replica.scene",
         folder({{"traj.txt", "1 0 0 0.5 0 1 0 -0.25 0 0 1 2 0 0 0 1\n"},
                 {"cam_params.json",
                  "{\"camera\": {\"w\": 1200, \"h\": 680, \"fx\": 600.0, \"fy\": 600.0, "
                  "\"cx\": 599.5, \"cy\": 339.5, \"scale\": 6553.5}}"},
                 {"results/depth000000.png", ""},
                 {"results/frame000000.jpg", ""}}));
    text(dir + "/kitti.scene", folder({{"poses.txt", kPose34 + "1 0 0 1.5 0 1 0 0 0 0 1 0\n"},
                                       {"calib.txt",
                                        "P0: 718.856 0 607.1928 0 0 718.856 185.2157 0 0 0 1 0\n"
                                        "Tr: 0 -1 0 -0.01 0 0 -1 -0.07 1 0 0 -0.27\n"},
                                       {"velodyne/000000.bin", velodyne()},
                                       {"velodyne/000001.bin", velodyne()}}));
    text(dir + "/sensors.scene",
         folder({{"bun.conf",
                  "camera -0.0172 -0.0013 0.2245 0 0 0 1\nbmesh bun000.ply 0 0 0 0 0 0 1\n"
                  "bmesh bun045.ply -0.0975 0.0019 -0.0030 0 0.3826834 0 0.9238795\n"},
                 {"sensors.txt", "# x y z\n0 0 1\n1.5 -2 3e-2\n"},
                 {"frame.pcd",
                  "VERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\n"
                  "COUNT 1 1 1 1\nWIDTH 2\nHEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\n"
                  "DATA ascii\n0 0 1 4.2e-39\nnan nan nan 0\n1 0 1 0\n0 1 1.5 0\n"}}));
}
}  // namespace

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: make_seeds DIR\n");
        return 2;
    }
    const std::string dir = argv[1];
    ::mkdir(dir.c_str(), 0755);
    for (const char* sub : {"ply", "xyz", "obj", "pcd", "las", "depth_png", "depth_exr",
                            "color_png", "color_jpg", "transforms", "layouts"}) {
        ::mkdir((dir + "/" + sub).c_str(), 0755);
    }
    seed_points(dir);
    seed_las(dir + "/las");
    seed_images(dir);
    seed_exr(dir + "/depth_exr");
    seed_jpeg(dir + "/color_jpg");
    seed_transforms(dir + "/transforms");
    seed_layouts(dir + "/layouts");
    return 0;
}
