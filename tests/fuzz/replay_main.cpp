// Replays a fuzz target's inputs without libFuzzer, so that every compiler and every CI build (the
// ASan one included) runs the seed corpus and the kept crashers: each argument is a file or a
// directory whose regular files are run once each, in name order. A missing directory counts as
// empty (a target may have no regressions yet), but no input at all is a failure: a mistyped path
// must not pass silently.

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace {

std::vector<std::filesystem::path> inputs_of(const std::filesystem::path& where) {
    std::vector<std::filesystem::path> out;
    std::error_code ec;
    if (std::filesystem::is_regular_file(where, ec)) {
        out.push_back(where);
    } else if (std::filesystem::is_directory(where, ec)) {
        for (const auto& entry : std::filesystem::directory_iterator(where)) {
            if (entry.is_regular_file()) {
                out.push_back(entry.path());
            }
        }
    }
    std::sort(out.begin(), out.end());
    return out;
}

}  // namespace

int main(int argc, char** argv) {
    std::size_t total = 0;
    for (int a = 1; a < argc; ++a) {
        const auto files = inputs_of(argv[a]);
        for (const auto& file : files) {
            std::ifstream in(file, std::ios::binary);
            const std::vector<char> bytes{std::istreambuf_iterator<char>(in),
                                          std::istreambuf_iterator<char>()};
            if (!in.good() && !in.eof()) {
                std::fprintf(stderr, "cannot read %s\n", file.c_str());
                return 1;
            }
            // A copy of exactly the input's size, as libFuzzer passes it, so ASan sees reads past
            // the end.
            std::vector<std::uint8_t> data(bytes.begin(), bytes.end());
            std::fprintf(stderr, "replay %s (%zu bytes)\n", file.c_str(), data.size());
            LLVMFuzzerTestOneInput(data.data(), data.size());
        }
        std::printf("%zu inputs from %s\n", files.size(), argv[a]);
        total += files.size();
    }
    if (total == 0) {
        std::fprintf(stderr, "no inputs found\n");
        return 1;
    }
    std::printf("replayed %zu inputs\n", total);
    return 0;
}
