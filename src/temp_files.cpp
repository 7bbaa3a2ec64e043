#include "detail/temp_files.h"
#include "vdbrecon/io.h"

#include <fcntl.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cstring>
#include <mutex>

namespace vdbrecon {
namespace {

constexpr std::size_t kSlots = 64;
constexpr std::size_t kPathMax = 4096;

struct Slot {
    std::atomic<bool> used{false};
    bool dir = false;  ///< a scratch directory: its entries, then itself
    char path[kPathMax];
};

std::array<Slot, kSlots>& slots() {
    static std::array<Slot, kSlots> s;
    return s;
}
std::mutex& slots_mutex() {
    static std::mutex m;
    return m;
}

}  // namespace

namespace detail {

namespace {

void add_slot(const std::string& path, bool dir) {
    if (path.size() + 1 > kPathMax) return;  // too long to track; still removed by its owner
    std::lock_guard<std::mutex> lock(slots_mutex());
    for (Slot& s : slots()) {
        if (!s.used.load()) {
            std::memcpy(s.path, path.c_str(), path.size() + 1);
            s.dir = dir;
            s.used.store(true);
            return;
        }
    }
}

/// Removes the entries of a flat directory, then the directory, with system calls only
/// (getdents64, unlinkat, rmdir: async-signal-safe, unlike opendir, which allocates).
void remove_flat_dir(const char* path) {
    const int fd = ::open(path, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0) return;
    alignas(8) char buf[4096];
    for (;;) {
        const long n = ::syscall(SYS_getdents64, fd, buf, sizeof buf);
        if (n <= 0) break;
        for (long at = 0; at < n;) {
            // struct linux_dirent64: d_ino (8), d_off (8), d_reclen (2), d_type (1), d_name
            unsigned short reclen;
            std::memcpy(&reclen, buf + at + 16, sizeof reclen);
            const char* name = buf + at + 19;
            if (std::strcmp(name, ".") != 0 && std::strcmp(name, "..") != 0) {
                ::unlinkat(fd, name, 0);
            }
            at += reclen;
        }
    }
    ::close(fd);
    ::rmdir(path);
}

}  // namespace

void register_temp_file(const std::string& path) { add_slot(path, false); }

void register_temp_dir(const std::string& path) { add_slot(path, true); }

void unregister_temp_file(const std::string& path) {
    std::lock_guard<std::mutex> lock(slots_mutex());
    for (Slot& s : slots()) {
        if (s.used.load() && path == s.path) {
            s.used.store(false);
            return;
        }
    }
}

}  // namespace detail

void remove_temp_files_now() {
    for (Slot& s : slots()) {
        if (!s.used.load()) continue;
        if (s.dir) {
            detail::remove_flat_dir(s.path);
        } else {
            ::unlink(s.path);
        }
    }
}

}  // namespace vdbrecon
