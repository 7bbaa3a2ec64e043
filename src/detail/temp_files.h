// A registry of temporary files currently being written, and of scratch directories (a tile
// job's: flat, files only), so that an interrupted run (SIGINT, SIGTERM) can remove them from
// a signal handler.
#pragma once

#include <string>

namespace vdbrecon::detail {

void register_temp_file(const std::string& path);
void register_temp_dir(const std::string& path);
/// Either kind.
void unregister_temp_file(const std::string& path);

}  // namespace vdbrecon::detail

