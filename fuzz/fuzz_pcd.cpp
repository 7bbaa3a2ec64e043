// libFuzzer target: the PCD reader (ascii, binary, LZF-compressed), as points (scripts/fuzz.sh).
#include "fuzz_reader.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    return vdbrecon::fuzz::read_all(data, size, "fuzz.pcd", false);
}
