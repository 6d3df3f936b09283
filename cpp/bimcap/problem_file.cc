#include "bimcap/problem_file.h"

#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <memory>
#include <set>
#include <sstream>

namespace bimcap {
namespace {

constexpr char kMagic[8] = {'B', 'I', 'M', 'C', 'A', 'P', 'P', 'F'};
constexpr uint32_t kDTypeF64 = 1, kDTypeI32 = 2, kDTypeU8 = 3;
constexpr const char* kOptionsName = "options";

static_assert(sizeof(double) == 8 && sizeof(int32_t) == 4, "unexpected type sizes");

bool HostIsLittleEndian() {
  const uint16_t one = 1;
  uint8_t first = 0;
  std::memcpy(&first, &one, 1);
  return first == 1;
}

template <typename T>
T Load(const uint8_t* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}

template <typename T>
void Store(uint8_t* p, T v) {
  std::memcpy(p, &v, sizeof(T));
}

uint64_t ItemSize(uint32_t dtype) {
  switch (dtype) {
    case kDTypeF64:
      return 8;
    case kDTypeI32:
      return 4;
    case kDTypeU8:
      return 1;
    default:
      return 0;
  }
}

const char* DTypeName(uint32_t dtype) {
  switch (dtype) {
    case kDTypeF64:
      return "float64";
    case kDTypeI32:
      return "int32";
    case kDTypeU8:
      return "uint8";
    default:
      return "?";
  }
}

uint64_t AlignUp(uint64_t v) {
  return (v + kProblemFileAlignment - 1) / kProblemFileAlignment * kProblemFileAlignment;
}

[[noreturn]] void Fail(const std::string& field, const std::string& message) {
  throw ProblemFileError(field, message);
}

// The options text must be printable ASCII lines ending in LF: a key or value with any other byte
// (a flipped bit, another encoding, CR) is reported here by line and column, and never reaches a
// message as raw bytes (which Python could not decode). (It is the only reader: Python calls it
// through _core.)
void CheckOptionsText(const std::string& text) {
  int line = 1, column = 0;
  for (const char ch : text) {
    const unsigned char c = static_cast<unsigned char>(ch);
    ++column;
    if (c == '\n') {
      ++line;
      column = 0;
    } else if (c < 0x20 || c > 0x7e) {
      char hex[8];
      std::snprintf(hex, sizeof(hex), "0x%02x", c);
      Fail(kOptionsName, "line " + std::to_string(line) + ", column " + std::to_string(column) +
                             ": byte " + hex +
                             " is not printable ASCII (options are key=value "
                             "text)");
    }
  }
}

// The fixed 64-byte header, checked against the file's size.
struct Header {
  uint32_t version = 0;
  uint32_t num_arrays = 0;
  uint64_t file_size = 0;
  uint64_t directory_end = 0;  // end of the header and the array directory
};

Header ParseHeader(const uint8_t* bytes, size_t size) {
  if (!HostIsLittleEndian()) Fail("header", "big-endian hosts are not supported");
  if (bytes == nullptr || size < kProblemFileHeaderSize) {
    Fail("header", "file too short for a header (" + std::to_string(size) + " bytes, need 64)");
  }
  if (std::memcmp(bytes, kMagic, sizeof(kMagic)) != 0) {
    Fail("header.magic", "not a bimcap problem file (bad magic)");
  }
  Header h;
  h.version = Load<uint32_t>(bytes + 8);
  const uint32_t header_size = Load<uint32_t>(bytes + 12);
  h.num_arrays = Load<uint32_t>(bytes + 16);
  const uint32_t entry_size = Load<uint32_t>(bytes + 20);
  h.file_size = Load<uint64_t>(bytes + 24);
  if (h.version != kProblemFileVersion) {
    Fail("header.version", "unsupported version " + std::to_string(h.version) +
                               " (this build reads version " + std::to_string(kProblemFileVersion) +
                               ")");
  }
  if (header_size != kProblemFileHeaderSize) Fail("header.header_size", "must be 64");
  if (entry_size != kProblemFileEntrySize) Fail("header.entry_size", "must be 64");
  if (h.num_arrays > kMaxArrays) {
    Fail("header.num_arrays", std::to_string(h.num_arrays) + " arrays (at most 256)");
  }
  if (h.file_size != size) {
    Fail("header.file_size", "header says " + std::to_string(h.file_size) +
                                 " bytes, the file has " + std::to_string(size) +
                                 " (truncated or padded?)");
  }
  h.directory_end = static_cast<uint64_t>(header_size) +
                    static_cast<uint64_t>(h.num_arrays) * kProblemFileEntrySize;
  if (h.directory_end > size) Fail("header.num_arrays", "directory runs past the end of the file");
  return h;
}

// Directory entry `index` (64 bytes at `entry`): its name, dtype and shape, checked on their own.
ArrayInfo ParseEntry(const uint8_t* entry, uint32_t index) {
  const std::string where = "array " + std::to_string(index);
  const void* nul = std::memchr(entry, 0, 32);
  if (nul == nullptr) Fail(where, "name is not NUL-terminated");
  ArrayInfo info;
  info.name.assign(reinterpret_cast<const char*>(entry), static_cast<const uint8_t*>(nul) - entry);
  if (info.name.empty()) Fail(where, "empty name");
  for (const char c : info.name) {
    if (!((c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_')) {
      Fail(where, "name has characters other than [a-z0-9_]");
    }
  }
  info.dtype = Load<uint32_t>(entry + 32);
  info.ndim = Load<uint32_t>(entry + 36);
  info.rows = Load<uint64_t>(entry + 40);
  info.cols = Load<uint64_t>(entry + 48);
  info.offset = Load<uint64_t>(entry + 56);
  return info;
}

// The array's size in bytes, after checking its dtype, shape and extent inside the file.
uint64_t CheckExtent(const ArrayInfo& info, size_t size, uint64_t directory_end) {
  const std::string& name = info.name;
  const uint64_t item = ItemSize(info.dtype);
  if (item == 0) Fail(name, "unknown dtype code " + std::to_string(info.dtype));
  if (info.ndim != 1 && info.ndim != 2) Fail(name, "ndim must be 1 or 2");
  if (info.ndim == 1 && info.cols != 1) Fail(name, "a 1-D array must have cols = 1");
  if (info.cols == 0 || info.cols > 64) Fail(name, "bad column count");
  // rows * cols * item must not overflow and must fit in the file.
  if (info.rows > (std::numeric_limits<uint64_t>::max() / info.cols) / item) {
    Fail(name, "size overflows");
  }
  const uint64_t nbytes = info.rows * info.cols * item;
  if (info.offset % kProblemFileAlignment != 0) Fail(name, "offset is not 64-byte aligned");
  if (info.offset < directory_end) Fail(name, "data overlaps the header or directory");
  if (info.offset > size || nbytes > size - info.offset) {
    Fail(name, "data runs past the end of the file (offset " + std::to_string(info.offset) + ", " +
                   std::to_string(nbytes) + " bytes, file " + std::to_string(size) + ")");
  }
  if (info.rows > static_cast<uint64_t>(std::numeric_limits<int32_t>::max())) {
    Fail(name, "too many rows");
  }
  return nbytes;
}

// A problem array: its dtype and shape must be those of its field (ProblemFields()).
void AttachArray(const ArrayInfo& info, const uint8_t* data, ProblemData* problem) {
  const std::string& name = info.name;
  const FieldSpec* spec = FindField(name);
  if (spec == nullptr) Fail(name, "unknown array");
  const uint32_t want = spec->dtype == DType::kFloat64 ? kDTypeF64 : kDTypeI32;
  if (info.dtype != want) {
    Fail(name, std::string("dtype ") + DTypeName(info.dtype) + ", expected " + DTypeName(want));
  }
  const uint64_t want_cols = spec->cols == 0 ? 1 : static_cast<uint64_t>(spec->cols);
  if (info.ndim != (spec->cols == 0 ? 1u : 2u) || info.cols != want_cols) {
    Fail(name, "expected " + std::string(spec->cols == 0 ? "a 1-D array" : "a 2-D array with ") +
                   (spec->cols == 0 ? "" : std::to_string(spec->cols) + " columns"));
  }
  const auto rows = static_cast<int64_t>(info.rows);
  const auto cols = static_cast<int64_t>(info.cols);
  if (spec->dtype == DType::kFloat64) {
    problem->Set(name, ArrayRef<double>{reinterpret_cast<const double*>(data), rows, cols});
  } else {
    problem->Set(name, ArrayRef<int32_t>{reinterpret_cast<const int32_t*>(data), rows, cols});
  }
}

// No two arrays share bytes, and every required array is there.
void CheckDirectory(std::vector<std::pair<uint64_t, uint64_t>> extents,
                    const std::set<std::string>& names) {
  std::sort(extents.begin(), extents.end());
  for (size_t i = 1; i < extents.size(); ++i) {
    if (extents[i].first < extents[i - 1].second) Fail("directory", "arrays overlap");
  }
  for (const FieldSpec& spec : ProblemFields()) {
    if (spec.required && names.count(spec.name) == 0) Fail(spec.name, "required array missing");
  }
}

}  // namespace

ProblemFile ParseProblemFile(const uint8_t* bytes, size_t size) {
  const Header header = ParseHeader(bytes, size);
  ProblemFile file;
  file.version = header.version;
  file.file_size = header.file_size;

  // One aligned copy; the views point into it.
  auto buffer = std::make_shared<std::vector<double>>((size + 7) / 8);
  uint8_t* base = reinterpret_cast<uint8_t*>(buffer->data());
  std::memcpy(base, bytes, size);

  std::set<std::string> names;
  std::vector<std::pair<uint64_t, uint64_t>> extents;  // [offset, end) of each array
  bool has_options = false;
  for (uint32_t i = 0; i < header.num_arrays; ++i) {
    ArrayInfo info = ParseEntry(
        base + kProblemFileHeaderSize + static_cast<uint64_t>(i) * kProblemFileEntrySize, i);
    if (!names.insert(info.name).second) Fail(info.name, "array given twice");
    const uint64_t nbytes = CheckExtent(info, size, header.directory_end);
    if (nbytes > 0) extents.emplace_back(info.offset, info.offset + nbytes);
    const uint8_t* data = base + info.offset;
    if (info.name == kOptionsName) {
      if (info.dtype != kDTypeU8 || info.ndim != 1) Fail(info.name, "must be a 1-D uint8 array");
      file.options_text.assign(reinterpret_cast<const char*>(data), nbytes);
      has_options = true;
    } else {
      AttachArray(info, data, &file.problem);
    }
    file.arrays.push_back(std::move(info));
  }
  CheckDirectory(std::move(extents), names);
  file.problem.owner = buffer;
  ValidateProblem(file.problem);
  if (has_options) CheckOptionsText(file.options_text);
  file.options = has_options ? OptionsFromText(file.options_text) : SolverOptions();
  return file;
}

ProblemFile ReadProblemFile(const std::string& path) {
  // A directory opens as a stream of "unknown" size on Linux; check the kind first.
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) {
    throw ProblemFileError(path, std::string("cannot open file: ") +
                                     (errno == ENOENT ? "no such file" : std::strerror(errno)));
  }
  if (S_ISDIR(st.st_mode)) throw ProblemFileError(path, "is a directory, not a problem file");
  if (!S_ISREG(st.st_mode)) throw ProblemFileError(path, "not a regular file");
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw ProblemFileError(path, "cannot open file");
  const std::streamoff size = in.tellg();
  if (size < 0) throw ProblemFileError(path, "cannot determine the file size");
  std::vector<uint8_t> bytes(static_cast<size_t>(size));
  in.seekg(0);
  if (size > 0 && !in.read(reinterpret_cast<char*>(bytes.data()), size)) {
    throw ProblemFileError(path, "read error");
  }
  try {
    return ParseProblemFile(bytes.data(), bytes.size());
  } catch (const ProblemFileError& e) {
    throw ProblemFileError(path + ": " + e.field(), e.message());
  } catch (const OptionsError& e) {
    throw OptionsError(path + ": " + e.field(), e.message());
  } catch (const ProblemError& e) {
    throw ProblemError(path + ": " + e.field(), e.message());
  }
}

std::vector<uint8_t> SerializeProblem(const ProblemData& problem, const SolverOptions& options) {
  ValidateProblem(problem);
  options.Check();
  struct Pending {
    ArrayInfo info;
    const void* data;
  };
  std::vector<Pending> arrays;
  for (const FieldSpec& spec : ProblemFields()) {
    ArrayInfo info;
    info.name = spec.name;
    info.ndim = spec.cols == 0 ? 1 : 2;
    const void* data = nullptr;
    if (spec.dtype == DType::kFloat64) {
      const ArrayRef<double> a = problem.F64(spec.name);
      info.dtype = kDTypeF64;
      info.rows = static_cast<uint64_t>(a.rows);
      info.cols = spec.cols == 0 ? 1 : spec.cols;
      data = a.data;
    } else {
      const ArrayRef<int32_t> a = problem.I32(spec.name);
      info.dtype = kDTypeI32;
      info.rows = static_cast<uint64_t>(a.rows);
      info.cols = spec.cols == 0 ? 1 : spec.cols;
      data = a.data;
    }
    arrays.push_back({info, data});
  }
  const std::string text = OptionsToText(options);
  arrays.push_back({ArrayInfo{kOptionsName, kDTypeU8, 1, text.size(), 1, 0}, text.data()});

  uint64_t offset = AlignUp(kProblemFileHeaderSize + arrays.size() * kProblemFileEntrySize);
  for (Pending& p : arrays) {
    p.info.offset = offset;
    offset = AlignUp(offset + p.info.rows * p.info.cols * ItemSize(p.info.dtype));
  }
  std::vector<uint8_t> out(offset, 0);
  std::memcpy(out.data(), kMagic, sizeof(kMagic));
  Store<uint32_t>(out.data() + 8, kProblemFileVersion);
  Store<uint32_t>(out.data() + 12, kProblemFileHeaderSize);
  Store<uint32_t>(out.data() + 16, static_cast<uint32_t>(arrays.size()));
  Store<uint32_t>(out.data() + 20, kProblemFileEntrySize);
  Store<uint64_t>(out.data() + 24, offset);
  for (size_t i = 0; i < arrays.size(); ++i) {
    uint8_t* entry = out.data() + kProblemFileHeaderSize + i * kProblemFileEntrySize;
    const ArrayInfo& info = arrays[i].info;
    std::memcpy(entry, info.name.data(), std::min<size_t>(info.name.size(), 31));
    Store<uint32_t>(entry + 32, info.dtype);
    Store<uint32_t>(entry + 36, info.ndim);
    Store<uint64_t>(entry + 40, info.rows);
    Store<uint64_t>(entry + 48, info.cols);
    Store<uint64_t>(entry + 56, info.offset);
    const uint64_t nbytes = info.rows * info.cols * ItemSize(info.dtype);
    if (nbytes > 0) std::memcpy(out.data() + info.offset, arrays[i].data, nbytes);
  }
  return out;
}

void WriteProblemFile(const std::string& path, const ProblemData& problem,
                      const SolverOptions& options) {
  const std::vector<uint8_t> bytes = SerializeProblem(problem, options);
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw ProblemFileError(path, "cannot open for writing");
    out.write(reinterpret_cast<const char*>(bytes.data()),
              static_cast<std::streamsize>(bytes.size()));
    out.close();
    if (!out) {  // a full disk shows here: leave no temporary file behind
      std::remove(tmp.c_str());
      throw ProblemFileError(path, "write error (disk full?)");
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw ProblemFileError(path, "cannot rename the temporary file into place");
  }
}

std::string DescribeProblemFile(const ProblemFile& file) {
  std::ostringstream o;
  o << "bimcap problem file, version " << file.version << ", " << file.file_size << " bytes, "
    << file.arrays.size() << " arrays\n";
  for (const ArrayInfo& a : file.arrays) {
    o << "  " << a.name;
    for (size_t i = a.name.size(); i < 18; ++i) o << ' ';
    o << DTypeName(a.dtype) << " (" << a.rows;
    if (a.ndim == 2) o << ", " << a.cols;
    o << ") @" << a.offset << "\n";
  }
  o << "options:\n";
  std::istringstream lines(file.options_text);
  std::string line;
  while (std::getline(lines, line)) o << "  " << line << "\n";
  return o.str();
}

}  // namespace bimcap
