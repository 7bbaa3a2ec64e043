// libFuzzer target: the LAS reader (versions 1.0-1.4, point formats 0-10), as points
// (scripts/fuzz.sh).
#include "fuzz_reader.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    return vdbrecon::fuzz::read_all(data, size, "fuzz.las", false);
}
