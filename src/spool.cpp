// Spool (see detail/spool.h).
#include "detail/spool.h"

#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>

#include "vdbrecon/error.h"

namespace vdbrecon::detail {

Spool::Spool(std::string what) : what_(std::move(what)) {
    const char* env = std::getenv("TMPDIR");
    dir_ = env && *env ? env : "/tmp";
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

std::string_view Spool::get(std::size_t i, std::string& buffer) const {
    buffer.resize(std::size_t(offsets_[i + 1] - offsets_[i]));
    read(i, buffer.data());
    return buffer;
}

}  // namespace vdbrecon::detail
