// libFuzzer target: the PLY reader (ascii and binary), as points and as a mesh (scripts/fuzz.sh).
#include "fuzz_reader.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    return vdbrecon::fuzz::read_all(data, size, "fuzz.ply", true);
}
