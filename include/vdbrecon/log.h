// Logging. The library never writes to stdout or stderr itself: warnings and progress go to a
// handler the application installs (the CLI prints them on stderr, Python forwards them).
#pragma once

#include <functional>
#include <string>

namespace vdbrecon {

enum class LogLevel { debug, info, warning };

/// Receives every message the library emits. Called from the calling thread only.
using LogHandler = std::function<void(LogLevel, const std::string&)>;

/// Installs `handler` (an empty function discards messages, the default) and returns the old one.
LogHandler set_log_handler(LogHandler handler);

/// Emits a message through the installed handler.
void log_message(LogLevel level, const std::string& message);

inline void log_info(const std::string& m) { log_message(LogLevel::info, m); }
inline void log_warning(const std::string& m) { log_message(LogLevel::warning, m); }
inline void log_debug(const std::string& m) { log_message(LogLevel::debug, m); }

}  // namespace vdbrecon
