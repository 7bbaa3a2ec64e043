// An unnamed temporary file that holds blocks of bytes a run does not need for a while, so that
// a large run holds in memory only what its current stage reads (the tiles' pieces while the
// cloud is in memory; the columns of a cloud the neighbour search does not read).
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>
#include <string_view>
#include <vector>

namespace vdbrecon::detail {

class Spool {
  public:
    /// An unnamed file in $TMPDIR (else /tmp), gone when closed, also after a crash. Throws
    /// IoError naming the directory when none can be made; `what` starts its messages.
    explicit Spool(std::string what);
    ~Spool();
    Spool(const Spool&) = delete;
    Spool& operator=(const Spool&) = delete;

    /// Appends a block; returns its number (0, 1, ...).
    std::size_t add(std::string_view bytes);
    /// Appends a vector's elements as a block.
    template <typename T>
    std::size_t add_vector(const std::vector<T>& v) {
        return add(std::string_view(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T)));
    }
    std::size_t size() const { return offsets_.size() - 1; }
    /// Block i, read into `buffer`.
    std::string_view get(std::size_t i, std::string& buffer) const;
    /// Block i as a vector (its size exact).
    template <typename T>
    std::vector<T> get_vector(std::size_t i) const {
        std::vector<T> v(std::size_t(offsets_[i + 1] - offsets_[i]) / sizeof(T));
        read(i, reinterpret_cast<char*>(v.data()));
        return v;
    }

    /// A spool used as a plain scratch file instead of blocks: n bytes at an offset (the file
    /// grows as needed; bytes never written read as zeros). Not mixed with add() on one spool.
    void write_at(std::uint64_t offset, const void* from, std::size_t n);
    void read_at(std::uint64_t offset, void* to, std::size_t n) const;

  private:
    void read(std::size_t i, char* to) const;
    std::FILE* file_ = nullptr;
    std::string what_, dir_;
    std::vector<std::uint64_t> offsets_{0};
};

/// A temporary directory in $TMPDIR (else /tmp), removed with what it holds when destroyed.
/// Throws IoError naming the directory when none can be made; `what` starts its messages.
class ScratchDir {
  public:
    explicit ScratchDir(const std::string& what);
    ~ScratchDir();
    ScratchDir(const ScratchDir&) = delete;
    ScratchDir& operator=(const ScratchDir&) = delete;
    const std::string& path() const { return path_; }

  private:
    std::string path_;
};

}  // namespace vdbrecon::detail
