#!/usr/bin/env bash
# Keep the problem-file fuzzer alive: when clang++ with libFuzzer is installed, build
# cpp/fuzz/problem_file_fuzzer (BIMCAP_FUZZ=ON: libFuzzer + ASan + UBSan on the reader) and run it
# for FUZZ_SECONDS (default 60) on the committed seed corpus cpp/fuzz/corpus/ (new inputs go to a
# scratch corpus under build/fuzz, the committed one is only read). A crash, a sanitizer report,
# a leak or an exception other than bimcap::InputError fails this script (and scripts/test.sh);
# the reproducer is left in build/fuzz/artifacts/. Without clang++/libFuzzer it skips with a line.
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_BUDGET=${FUZZ_SECONDS:-60}
CXX_FUZZ=${CXX_FUZZ:-clang++}

if ! command -v "$CXX_FUZZ" >/dev/null 2>&1; then
  echo "==> fuzz: skipped ($CXX_FUZZ not found; apt-get install clang libclang-rt-14-dev to run it)"
  exit 0
fi
probe=$(mktemp -d)
trap 'rm -rf "$probe"' EXIT
printf '%s\n' 'extern "C" int LLVMFuzzerTestOneInput(const unsigned char*, unsigned long) {' \
  '  return 0;' '}' > "$probe/probe.cc"
if ! "$CXX_FUZZ" -fsanitize=fuzzer,address,undefined "$probe/probe.cc" -o "$probe/probe" \
     >/dev/null 2>&1; then
  echo "==> fuzz: skipped ($CXX_FUZZ has no libFuzzer runtime; apt-get install libclang-rt-14-dev)"
  exit 0
fi

echo "==> fuzz: building cpp/fuzz/problem_file_fuzzer with $CXX_FUZZ (libFuzzer, ASan, UBSan)"
cmake -S . -B build/fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
      -DCMAKE_CXX_COMPILER="$CXX_FUZZ" -DBIMCAP_FUZZ=ON -DBIMCAP_BUILD_TESTS=OFF \
      -DBIMCAP_PYTHON=OFF >/dev/null
cmake --build build/fuzz --target problem_file_fuzzer -j "$(nproc)"
mkdir -p build/fuzz/corpus build/fuzz/artifacts
echo "==> fuzz: running for ${SECONDS_BUDGET} s on cpp/fuzz/corpus/"
build/fuzz/cpp/problem_file_fuzzer -max_total_time="$SECONDS_BUDGET" -max_len=65536 \
  -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
  -artifact_prefix=build/fuzz/artifacts/ build/fuzz/corpus cpp/fuzz/corpus
echo "==> fuzz: no finding in ${SECONDS_BUDGET} s"
