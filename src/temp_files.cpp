#include "detail/temp_files.h"
#include "vdbrecon/io.h"

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

void register_temp_file(const std::string& path) {
    if (path.size() + 1 > kPathMax) return;  // too long to track; still removed by its owner
    std::lock_guard<std::mutex> lock(slots_mutex());
    for (Slot& s : slots()) {
        if (!s.used.load()) {
            std::memcpy(s.path, path.c_str(), path.size() + 1);
            s.used.store(true);
            return;
        }
    }
}

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
        if (s.used.load()) ::unlink(s.path);
    }
}

}  // namespace vdbrecon
