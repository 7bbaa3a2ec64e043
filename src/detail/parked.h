// Columns of a cloud parked in an unnamed temporary file (detail/spool.h) while a stage that
// does not read them runs: a 20M-point cloud's normals (229 MiB) would otherwise sit beside the
// neighbour search's index and tables.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <type_traits>

#include "detail/spool.h"
#include "vdbrecon/error.h"
#include "vdbrecon/log.h"
#include "vdbrecon/types.h"

namespace vdbrecon::detail {

/// Which columns to park (a mask).
enum ParkColumn : unsigned {
    kParkNormals = 1,
    kParkColors = 2,
    kParkScales = 4,
    kParkConfidences = 8,
    kParkAll = 15,
};

/// The cloud's owned columns in `which` wait in a spool from construction to restore(), when
/// they hold at least `min_bytes` together; borrowed columns stay. Where no temporary file can
/// be made they stay in memory (a warning naming `stage` says so). When a stage throws before
/// restore(), the destructor puts them back (as far as the file can still be read: it does not
/// throw).
class ParkedColumns {
  public:
    ParkedColumns(PointCloud& cloud, std::size_t min_bytes, unsigned which,
                  const std::string& stage)
        : cloud_(cloud), which_(which) {
        std::size_t bytes = 0;
        for_each([&](auto& c) { bytes += c.borrowed() ? 0 : c.size() * sizeof(c[0]); });
        if (bytes == 0 || bytes < min_bytes) return;
        try {
            spool_ = std::make_unique<Spool>(stage + ": parking the cloud's columns");
            for_each([&](auto& c) {
                if (!c.borrowed()) {
                    spool_->add_vector(c.edit());
                    c.clear();
                }
            });
        } catch (const IoError& e) {
            restore();
            log_warning(std::string(e.what()) + "; they stay in memory");
        }
    }
    ~ParkedColumns() {
        try {
            restore();
        } catch (...) {  // already unwinding from the stage's own error
        }
    }
    ParkedColumns(const ParkedColumns&) = delete;
    ParkedColumns& operator=(const ParkedColumns&) = delete;

    /// Puts the columns back (exactly sized).
    void restore() {
        if (!spool_) return;
        std::size_t block = 0;
        for_each([&](auto& c) {
            using T = std::decay_t<decltype(c[0])>;
            if (!c.borrowed() && block < spool_->size()) c = spool_->get_vector<T>(block++);
        });
        spool_.reset();
    }

  private:
    template <typename Fn>
    void for_each(Fn&& fn) {
        if (which_ & kParkNormals) fn(cloud_.normals);
        if (which_ & kParkColors) fn(cloud_.colors);
        if (which_ & kParkScales) fn(cloud_.scales);
        if (which_ & kParkConfidences) fn(cloud_.confidences);
    }
    PointCloud& cloud_;
    unsigned which_;
    std::unique_ptr<Spool> spool_;
};

}  // namespace vdbrecon::detail
