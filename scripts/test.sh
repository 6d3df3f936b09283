#!/usr/bin/env bash
# Set up, then run every test: the C++ suite (CTest + GoogleTest) and the Python suite (pytest).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh

echo "==> C++ tests (CTest)"
cmake -S . -B build/ctest -G Ninja -DCMAKE_BUILD_TYPE=Release -DBIMCAP_BUILD_TESTS=ON -DBIMCAP_PYTHON=OFF >/dev/null
cmake --build build/ctest -j "$(nproc)"
ctest --test-dir build/ctest --output-on-failure -j "$(nproc)"

echo "==> C++ format (clang-format, .clang-format)"
find cpp \( -name '*.cc' -o -name '*.h' \) -print0 | xargs -0 clang-format --dry-run --Werror

echo "==> Lint (ruff)"
.venv/bin/python -m ruff check python tests bench

echo "==> Type checks (mypy, strict on bimcap.optimize, .geometry, .evaluation, .io: see pyproject.toml)"
.venv/bin/python -m mypy python/bimcap/optimize python/bimcap/geometry python/bimcap/evaluation python/bimcap/io

echo "==> Python tests (pytest)"
.venv/bin/python -m pytest tests

echo "==> Fuzzing the problem-file reader (skipped without clang++ / libFuzzer)"
bash scripts/fuzz.sh
