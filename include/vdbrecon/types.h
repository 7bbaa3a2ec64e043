// vdbrecon: surface reconstruction from oriented point clouds on OpenVDB grids.
//
// Core data types shared by every stage. Points and meshes are structures of arrays whose
// per-point attributes are N x 3 row-major float arrays (Vec3f rows), so they map to numpy
// (N, 3) float32 arrays without copies: the arrays of PointCloud and Mesh are Columns, which
// either own a std::vector or borrow someone else's memory (a numpy array, a caller's buffer).
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace vdbrecon {

/// A 3-vector of floats; 12 bytes, no padding, so std::vector<Vec3f> is an N x 3 float array.
using Vec3f = std::array<float, 3>;
/// A 3-vector of doubles (world-frame origins, viewpoints).
using Vec3d = std::array<double, 3>;
/// A triangle: three vertex indices, counter-clockwise seen from outside.
using Triangle = std::array<std::int32_t, 3>;

static_assert(sizeof(Vec3f) == 12, "Vec3f must be three packed floats");
static_assert(sizeof(Triangle) == 12, "Triangle must be three packed int32");

/// A read-only view of contiguous values: what functions that only read an array take, so both
/// a std::vector and a Column (owning or borrowed) can be passed without a copy.
template <typename T>
class Span {
  public:
    Span() = default;
    Span(const T* data, std::size_t size) : data_(data), size_(size) {}
    Span(const std::vector<T>& v) : data_(v.data()), size_(v.size()) {}  // NOLINT: implicit

    const T* data() const { return data_; }
    std::size_t size() const { return size_; }
    bool empty() const { return size_ == 0; }
    const T& operator[](std::size_t i) const { return data_[i]; }
    const T* begin() const { return data_; }
    const T* end() const { return data_ + size_; }

  private:
    const T* data_ = nullptr;
    std::size_t size_ = 0;
};

/// One per-point attribute array. It owns its values (a std::vector, the usual case), or borrows
/// memory it does not own (Column::borrow: numpy arrays passed to the Python module, a caller's
/// buffer), kept alive by an optional `keeper` for as long as the column or a copy of it lives.
///
/// Reading is the same either way (size, [], data, begin/end, Span). Writing goes through
/// edit(), which first turns a borrowed column into an owned copy of its values, so the
/// borrowed memory is never written to; assigning a vector replaces the values. Copying a
/// borrowed column copies the reference, not the values.
template <typename T>
class Column {
  public:
    Column() = default;
    Column(std::vector<T> values) : own_(std::move(values)) {}  // NOLINT: implicit
    Column(std::initializer_list<T> values) : own_(values) {}

    /// A column reading `size` values at `data` without copying them. `keeper` (may be empty)
    /// is held while the column or any copy of it lives; without one, the caller guarantees
    /// that `data` outlives them.
    static Column borrow(const T* data, std::size_t size,
                         std::shared_ptr<const void> keeper = nullptr) {
        Column c;
        c.ext_ = size ? data : nullptr;
        c.ext_size_ = size;
        c.borrowed_ = true;
        c.keeper_ = std::move(keeper);
        return c;
    }
    /// A borrowed column reading this one's values; valid while this one is alive and unchanged.
    Column view() const { return borrow(data(), size()); }

    bool borrowed() const { return borrowed_; }
    const T* data() const { return borrowed_ ? ext_ : own_.data(); }
    std::size_t size() const { return borrowed_ ? ext_size_ : own_.size(); }
    bool empty() const { return size() == 0; }
    const T& operator[](std::size_t i) const { return data()[i]; }
    const T* begin() const { return data(); }
    const T* end() const { return data() + size(); }
    operator Span<T>() const { return Span<T>(data(), size()); }  // NOLINT: implicit
    std::vector<T> to_vector() const { return std::vector<T>(begin(), end()); }

    /// The values as an owned vector to modify; a borrowed column copies them first.
    std::vector<T>& edit() {
        if (borrowed_) {
            own_.assign(ext_, ext_ + ext_size_);
            release();
        }
        return own_;
    }
    /// Takes the values out as a vector (copied when borrowed); the column is left empty.
    std::vector<T> release_vector() {
        std::vector<T> v = std::move(edit());
        own_.clear();
        return v;
    }
    // The std::vector mutators used to fill a column, all through edit().
    void resize(std::size_t n) { edit().resize(n); }
    void resize(std::size_t n, const T& value) { edit().resize(n, value); }
    void assign(std::size_t n, const T& value) { edit().assign(n, value); }
    void reserve(std::size_t n) { edit().reserve(n); }
    void push_back(const T& value) { edit().push_back(value); }
    void clear() { *this = std::vector<T>(); }

    friend bool operator==(const Column& a, const Column& b) {
        return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin());
    }
    friend bool operator!=(const Column& a, const Column& b) { return !(a == b); }

  private:
    void release() {
        borrowed_ = false;
        ext_ = nullptr;
        ext_size_ = 0;
        keeper_.reset();
    }

    std::vector<T> own_;
    const T* ext_ = nullptr;
    std::size_t ext_size_ = 0;
    bool borrowed_ = false;
    std::shared_ptr<const void> keeper_;
};

/// An unstructured point sample of a surface.
///
/// Positions are stored relative to `origin` (world = origin + position) so that georeferenced
/// coordinates (e.g. 1e7 m) keep float precision. Every optional attribute is either empty or
/// has exactly one entry per point. Any of the arrays may borrow memory (Column::borrow): the
/// stages only read their input cloud, and the pipeline replaces (never writes into) arrays.
struct PointCloud {
    Column<Vec3f> positions;    ///< #P by 3, world units, relative to `origin`
    Column<Vec3f> normals;      ///< #P by 3 or empty; unit length, pointing out of the object
    Column<Vec3f> colors;       ///< #P by 3 or empty; linear 0..1 RGB
    Column<float> scales;       ///< #P or empty; sample footprint (spacing), world units
    Column<float> confidences;  ///< #P or empty; per-point confidence (file-defined units)
    Vec3d origin{0.0, 0.0, 0.0};  ///< world position of the local frame's origin

    std::size_t size() const { return positions.size(); }
    bool empty() const { return positions.empty(); }
    bool has_normals() const { return !normals.empty(); }
    bool has_colors() const { return !colors.empty(); }
    bool has_scales() const { return !scales.empty(); }
    bool has_confidences() const { return !confidences.empty(); }
    /// Bytes of its arrays (owned or borrowed).
    std::size_t memory_bytes() const {
        return (positions.size() + normals.size() + colors.size()) * sizeof(Vec3f) +
               (scales.size() + confidences.size()) * sizeof(float);
    }
    /// A cloud borrowing every array of this one (no copies); valid while this one is alive and
    /// unchanged.
    PointCloud view() const {
        PointCloud c;
        c.positions = positions.view();
        c.normals = normals.view();
        c.colors = colors.view();
        c.scales = scales.view();
        c.confidences = confidences.view();
        c.origin = origin;
        return c;
    }
};

/// An indexed triangle mesh. Vertices are relative to `origin`, like PointCloud positions; its
/// arrays are Columns too (a mesh built from numpy arrays borrows them).
struct Mesh {
    Column<Vec3f> vertices;    ///< #V by 3, world units, relative to `origin`
    Column<Vec3f> normals;     ///< #V by 3 or empty; unit outward vertex normals
    Column<Vec3f> colors;      ///< #V by 3 or empty; linear 0..1 RGB
    Column<Triangle> faces;    ///< #F by 3, counter-clockwise seen from outside
    /// #F or empty: per face, the planar region it belongs to (planes.h; -1 = none). Written
    /// as the PLY face property `region`.
    Column<std::int32_t> regions;
    Vec3d origin{0.0, 0.0, 0.0};    ///< world position of the local frame's origin

    bool empty() const { return faces.empty(); }
};

/// Axis-aligned bounding box of float positions; empty when min > max.
struct BBox {
    Vec3f min{1.0f, 1.0f, 1.0f};
    Vec3f max{0.0f, 0.0f, 0.0f};
    bool empty() const { return min[0] > max[0]; }
    /// Length of the diagonal (0 for an empty box).
    double diagonal() const;
};

/// Bounding box of a set of positions.
BBox bounding_box(Span<Vec3f> positions);

}  // namespace vdbrecon
