// libFuzzer target for the problem-file reader. Build with clang:
//   CXX=clang++ cmake -S . -B build/fuzz -DBIMCAP_FUZZ=ON -DBIMCAP_BUILD_TESTS=OFF
//   cmake --build build/fuzz --target problem_file_fuzzer
//   build/fuzz/cpp/problem_file_fuzzer -max_len=65536 corpus/
// Seed the corpus with files from bimcap.optimize.write_problem. Any input must either parse or
// throw bimcap::InputError; anything else (a crash, an ASan report, another exception) is a bug.
#include <cstddef>
#include <cstdint>

#include "bimcap/problem_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    bimcap::ParseProblemFile(data, size);
  } catch (const bimcap::InputError&) {
  }
  return 0;
}
