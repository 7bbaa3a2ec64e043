// When the launcher (apps/launcher.cpp) asks glibc for transparent huge pages: where the kernel
// hands them out on request and the memory a run faults in is this machine's to keep.
//
// A virtual machine whose memory balloon reports free pages to the host (virtio's
// VIRTIO_BALLOON_F_REPORTING, e.g. Firecracker, QEMU with free-page-reporting=on) hands memory
// back within a second of its being freed, and a run that starts later faults every page in
// anew. On such a machine (the 2-core dev VM: Firecracker, balloon feature bit 5 on) a 2 MB
// page on memory the host must back again faulted at 0.24-0.5 GB/s against ~3 GB/s for 4 kB
// pages, and the first run after 3 s idle was 24-30 % slower with huge pages (bunny at 0.5 mm:
// 0.69-0.87 s against 0.61-0.69 s; dragon 1.18-1.21 against 0.90-0.93 s; room 1.62-1.65
// against 1.24-1.33 s), while runs back to back were 2-6 % faster with them. A user's run is
// mostly the first in a while, so there the launcher leaves glibc's pages as they are.
//
// Header-only, with the sysfs root as a parameter, so that tests can give it a made-up tree.
#pragma once

#include <dirent.h>
#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <string>

namespace vdbrecon::launcher {

/// The first line of a file, without its newline ("" where it cannot be read).
inline std::string first_line(const std::string& path) {
    std::FILE* f = std::fopen(path.c_str(), "r");
    if (!f) return "";
    char line[512] = {};
    const bool read = std::fgets(line, sizeof line, f) != nullptr;
    std::fclose(f);
    if (!read) return "";
    line[std::strcspn(line, "\n")] = '\0';
    return line;
}

/// True when the kernel's transparent huge page mode is "madvise" (`sys`: sysfs, "/sys"). Mode
/// "always" needs no advice, "never" ignores it.
inline bool thp_on_request(const std::string& sys) {
    return first_line(sys + "/kernel/mm/transparent_hugepage/enabled").find("[madvise]") !=
           std::string::npos;
}

/// True when a virtio memory balloon with a driver bound reports free pages to the host: device
/// id 0x0005 (balloon) whose negotiated features (a string of 0s and 1s, bit 0 first) have bit 5,
/// VIRTIO_BALLOON_F_REPORTING, set.
inline bool free_memory_goes_to_host(const std::string& sys) {
    const std::string root = sys + "/bus/virtio/devices";
    DIR* dir = opendir(root.c_str());
    if (!dir) return false;
    bool reporting = false;
    while (const dirent* e = readdir(dir)) {
        if (e->d_name[0] == '.') continue;
        const std::string device = root + "/" + e->d_name;
        if (first_line(device + "/device") != "0x0005") continue;
        if (access((device + "/driver").c_str(), F_OK) != 0) continue;
        const std::string features = first_line(device + "/features");
        if (features.size() > 5 && features[5] == '1') reporting = true;
    }
    closedir(dir);
    return reporting;
}

/// Whether the launcher adds glibc's huge-page tunables (see above).
inline bool huge_pages_help(const std::string& sys) {
    return thp_on_request(sys) && !free_memory_goes_to_host(sys);
}

}  // namespace vdbrecon::launcher
