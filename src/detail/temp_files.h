// A registry of temporary files currently being written, so that an interrupted run (SIGINT,
// SIGTERM) can remove them from a signal handler.
#pragma once

#include <string>

namespace vdbrecon::detail {

void register_temp_file(const std::string& path);
void unregister_temp_file(const std::string& path);

}  // namespace vdbrecon::detail

