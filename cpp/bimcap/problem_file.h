// The problem file: one versioned binary file with every input of a solve.
//
// Layout (little-endian; every offset a multiple of 64 so that numpy can np.frombuffer / memmap
// each array without copying):
//
//   offset 0   header, 64 bytes
//     char[8]  magic "BIMCAPPF"
//     u32      version (kProblemFileVersion)
//     u32      header_size (64)
//     u32      num_arrays (<= kMaxArrays)
//     u32      entry_size (64)
//     u64      file_size (must equal the real size)
//     u8[32]   reserved, zero
//   offset 64  directory, num_arrays entries of 64 bytes
//     char[32] name, NUL-padded ([a-z0-9_], unique; the names of ProblemFields() and "options")
//     u32      dtype (1 float64, 2 int32, 3 uint8)
//     u32      ndim (1 or 2)
//     u64      rows
//     u64      cols (1 when ndim = 1)
//     u64      offset of the data (a multiple of 64, past the directory, arrays do not overlap)
//   data       each array C-contiguous at its offset, zero padding between arrays
//
// The `options` array (uint8) holds the solver options as "key=value\n" text (OptionsToText).
// Every malformed file raises ProblemFileError (or ProblemError / OptionsError for bad content)
// naming the field; nothing is read outside the buffer.
#ifndef BIMCAP_PROBLEM_FILE_H_
#define BIMCAP_PROBLEM_FILE_H_

#include <cstdint>
#include <string>
#include <vector>

#include "bimcap/options.h"
#include "bimcap/problem.h"

namespace bimcap {

inline constexpr uint32_t kProblemFileVersion = 1;
inline constexpr uint32_t kProblemFileHeaderSize = 64;
inline constexpr uint32_t kProblemFileEntrySize = 64;
inline constexpr uint32_t kProblemFileAlignment = 64;
inline constexpr uint32_t kMaxArrays = 256;

class ProblemFileError : public InputError {
 public:
  using InputError::InputError;
};

struct ArrayInfo {
  std::string name;
  uint32_t dtype = 0;
  uint32_t ndim = 0;
  uint64_t rows = 0;
  uint64_t cols = 0;
  uint64_t offset = 0;
};

struct ProblemFile {
  uint32_t version = 0;
  uint64_t file_size = 0;
  std::vector<ArrayInfo> arrays;
  ProblemData problem;  // views into the file's buffer (problem.owner keeps it alive)
  SolverOptions options;
  std::string options_text;
};

// Parses and validates a problem held in memory (the bytes are copied into an aligned buffer).
ProblemFile ParseProblemFile(const uint8_t* data, size_t size);
// Reads and validates a file; errors are prefixed with the path.
ProblemFile ReadProblemFile(const std::string& path);

// The file's bytes for `problem` and `options` (validated first).
std::vector<uint8_t> SerializeProblem(const ProblemData& problem, const SolverOptions& options);
// Writes atomically (temporary file in the same directory, then rename).
void WriteProblemFile(const std::string& path, const ProblemData& problem,
                      const SolverOptions& options);

// A human-readable listing of the header and arrays (bimcap_solve --info).
std::string DescribeProblemFile(const ProblemFile& file);

}  // namespace bimcap

#endif  // BIMCAP_PROBLEM_FILE_H_
