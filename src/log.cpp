#include "vdbrecon/log.h"

#include <mutex>

namespace vdbrecon {
namespace {

std::mutex& handler_mutex() {
    static std::mutex m;
    return m;
}
LogHandler& handler() {
    static LogHandler h;
    return h;
}

}  // namespace

LogHandler set_log_handler(LogHandler h) {
    std::lock_guard<std::mutex> lock(handler_mutex());
    std::swap(handler(), h);
    return h;
}

void log_message(LogLevel level, const std::string& message) {
    std::lock_guard<std::mutex> lock(handler_mutex());
    if (handler()) handler()(level, message);
}

}  // namespace vdbrecon
