// Spool (see detail/spool.h).
#include "detail/spool.h"

#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>

#include "detail/temp_files.h"
#include "vdbrecon/error.h"

namespace vdbrecon::detail {

namespace {

/// Where temporary files go: $TMPDIR, else /tmp.
std::string temp_dir() {
    const char* env = std::getenv("TMPDIR");
    return env && *env ? env : "/tmp";
}

}  // namespace

Spool::Spool(std::string what) : what_(std::move(what)), dir_(temp_dir()) {
    std::string name = dir_ + "/vdbrecon-spool-XXXXXX";
    const int fd = ::mkstemp(name.data());
    if (fd < 0) {
        throw IoError(what_ + ": cannot make a temporary file in " + dir_ + ": " +
                      std::strerror(errno) + " (set TMPDIR to a writable directory)");
    }
    ::unlink(name.c_str());  // unnamed from here on
    file_ = ::fdopen(fd, "w+b");
    if (!file_) {
        ::close(fd);
        throw IoError(what_ + ": cannot open a temporary file in " + dir_);
    }
}

Spool::~Spool() {
    if (file_) std::fclose(file_);
}

std::size_t Spool::add(std::string_view bytes) {
    if (::fseeko(file_, off_t(offsets_.back()), SEEK_SET) != 0 ||
        std::fwrite(bytes.data(), 1, bytes.size(), file_) != bytes.size()) {
        throw IoError(what_ + ": writing to a temporary file in " + dir_ + " failed (disk full?)");
    }
    offsets_.push_back(offsets_.back() + bytes.size());
    return size() - 1;
}

void Spool::read(std::size_t i, char* to) const {
    const std::size_t n = std::size_t(offsets_[i + 1] - offsets_[i]);
    if (std::fflush(file_) != 0 || ::fseeko(file_, off_t(offsets_[i]), SEEK_SET) != 0 ||
        std::fread(to, 1, n, file_) != n) {
        throw IoError(what_ + ": reading back from a temporary file in " + dir_ + " failed");
    }
}

void Spool::write_at(std::uint64_t offset, const void* from, std::size_t n) {
    const char* p = static_cast<const char*>(from);
    while (n > 0) {
        const ssize_t w = ::pwrite(::fileno(file_), p, n, off_t(offset));
        if (w <= 0) {
            throw IoError(what_ + ": writing to a temporary file in " + dir_ +
                          " failed (disk full?)");
        }
        p += w;
        n -= std::size_t(w);
        offset += std::uint64_t(w);
    }
}

void Spool::read_at(std::uint64_t offset, void* to, std::size_t n) const {
    char* p = static_cast<char*>(to);
    while (n > 0) {
        const ssize_t r = ::pread(::fileno(file_), p, n, off_t(offset));
        if (r < 0) throw IoError(what_ + ": reading back from a temporary file in " + dir_ + " failed");
        if (r == 0) {  // beyond what was written: zeros
            std::memset(p, 0, n);
            return;
        }
        p += r;
        n -= std::size_t(r);
        offset += std::uint64_t(r);
    }
}

std::string_view Spool::get(std::size_t i, std::string& buffer) const {
    buffer.resize(std::size_t(offsets_[i + 1] - offsets_[i]));
    read(i, buffer.data());
    return buffer;
}

ScratchDir::ScratchDir(const std::string& what) {
    const std::string dir = temp_dir();
    std::string name = dir + "/vdbrecon-tiles-XXXXXX";
    if (!::mkdtemp(name.data())) {
        throw IoError(what + ": cannot make a temporary directory in " + dir + ": " +
                      std::strerror(errno) + " (set TMPDIR to a writable directory)");
    }
    path_ = name;
    register_temp_dir(path_);  // removed by remove_temp_files_now() on SIGINT / SIGTERM too
}

ScratchDir::~ScratchDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
    unregister_temp_file(path_);
}

}  // namespace vdbrecon::detail
