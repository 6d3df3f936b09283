// libFuzzer target for the problem-file reader (with ASan and UBSan). scripts/fuzz.sh builds it
// with clang and runs it for 60 s on the committed seed corpus cpp/fuzz/corpus/ (written by
// cpp/fuzz/make_corpus.py through bimcap.optimize.write_problem); scripts/test.sh calls it.
// By hand:
//   cmake -S . -B build/fuzz -DCMAKE_CXX_COMPILER=clang++ -DBIMCAP_FUZZ=ON -DBIMCAP_BUILD_TESTS=OFF
//   cmake --build build/fuzz --target problem_file_fuzzer
//   build/fuzz/cpp/problem_file_fuzzer -max_len=65536 build/fuzz/corpus cpp/fuzz/corpus
// Any input must either parse or throw bimcap::InputError; anything else (a crash, a sanitizer
// report, another exception such as std::bad_alloc) is a bug.
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
