// vdbrecon: the command a user runs. It sets glibc's huge-page tunables and executes the real
// command line, vdbrecon-core, from the same directory, so that the process that does the work
// starts with them.
//
// glibc reads its tunables (GLIBC_TUNABLES) only when a process starts. glibc.malloc.hugetlb=1
// (glibc >= 2.35) makes malloc advise transparent huge pages for the memory it takes from the
// kernel, so a run faults its heap in 2 MB at a time instead of 4 kB (bunny at 0.5 mm: 33.8k ->
// 2.3k page faults; on the 2-core VM, runs back to back 2-6 % faster).
// glibc advises only heap growths of at least 2 MB, so glibc.malloc.top_pad=64 MB grows the heap
// 64 MB (of address space) at a time from the start; a small run's heap would otherwise never
// get a huge page. The tunables are added only where the kernel hands out huge pages on request
// (THP mode "madvise", Debian's default: "always" needs no advice, "never" ignores it), not on a
// virtual machine that hands freed memory back to its host (apps/huge_pages.h: there a run that
// faults its memory in anew was a quarter slower with huge pages), and when GLIBC_TUNABLES does
// not name glibc.malloc.hugetlb already (set it to 0 to turn this off).
//
// Before, the command line executed itself once more with the tunables, which loaded
// libopenvdb.so twice. Loading it is expensive: it is linked with BIND_NOW, so the dynamic
// linker resolves its 64k relocations before main (70 ms on the 2-core VM). This program needs
// only libc and libstdc++ and starts in about a millisecond.
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "huge_pages.h"

namespace {

/// The directory this executable is in ("" where /proc/self/exe cannot be read).
std::string own_directory() {
    std::string path(4096, '\0');
    const ssize_t n = readlink("/proc/self/exe", &path[0], path.size());
    if (n <= 0 || std::size_t(n) >= path.size()) return "";
    path.resize(std::size_t(n));
    return path.substr(0, path.rfind('/') + 1);
}

}  // namespace

int main(int, char** argv) {
    const char* old = std::getenv("GLIBC_TUNABLES");
    const std::string previous = old ? old : "";
    if (previous.find("glibc.malloc.hugetlb") == std::string::npos &&
        vdbrecon::launcher::huge_pages_help("/sys")) {
        const std::string value =
            (previous.empty() ? "" : previous + ":") +
            "glibc.malloc.hugetlb=1:glibc.malloc.top_pad=" + std::to_string(64 << 20);
        setenv("GLIBC_TUNABLES", value.c_str(), 1);  // on failure the run goes on without
    }
    const std::string core = own_directory() + "vdbrecon-core";
    execv(core.c_str(), argv);
    std::fprintf(stderr, "vdbrecon: error: cannot run %s: %s\n", core.c_str(),
                 std::strerror(errno));
    return 4;  // vdbrecon's "anything else"
}
