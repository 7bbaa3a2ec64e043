// libFuzzer target: read_color_image of a JPEG colour image (libjpeg-turbo) (scripts/fuzz.sh).
#include "fuzz_scene.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    return vdbrecon::fuzz::read_color(data, size, "jpg");
}
