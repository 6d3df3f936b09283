// bimcap_solve PROBLEM -o OUT: solve a problem file, write OUT/refined.tum and OUT/summary.json.
//
// Exit codes: 0 solved, 1 usage error, 2 bad input (unreadable or malformed problem file, bad
// option), 3 the solve failed (Ceres reported an unusable solution, or the cost is not finite),
// 4 the outputs could not be written (permission denied, read-only file system, disk full, OUT is
// a file); the same codes as the `bimcap` command line (docs/reliability.md).
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <iostream>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "bimcap/problem_file.h"
#include "bimcap/solver.h"

namespace {

constexpr int kExitUsage = 1;
constexpr int kExitBadInput = 2;
constexpr int kExitSolveFailed = 3;
constexpr int kExitOutput = 4;

// A file-system failure while writing the outputs (exit kExitOutput).
class OutputError : public std::runtime_error {
 public:
  OutputError(const std::string& path, int error)
      : std::runtime_error(path + ": " + Reason(error)) {}

  static std::string Reason(int error) {
    switch (error) {
      case EACCES:
      case EPERM:
        return "permission denied";
      case EROFS:
        return "read-only file system";
      case ENOSPC:
        return "no space left on the device (disk full)";
#ifdef EDQUOT
      case EDQUOT:
        return "disk quota exceeded";
#endif
      case EFBIG:
        return "file too large (file-size limit reached)";
      case ENOTDIR:
        return "not a directory (a file is in the way)";
      case EISDIR:
        return "is a directory";
      case ENOENT:
        return "no such file or directory";
      default:
        return std::strerror(error);
    }
  }
};

const char kUsage[] =
    "usage: bimcap_solve PROBLEM -o OUT [--set KEY=VALUE ...] [--threads N] [--quiet]\n"
    "       bimcap_solve PROBLEM --info\n"
    "\n"
    "Solve a bimcap problem file (written by bimcap.optimize.write_problem) and write\n"
    "  OUT/refined.tum    refined world_from_cam poses, 'timestamp tx ty tz qx qy qz qw'\n"
    "  OUT/summary.json   costs per term before/after, iterations, time, termination\n"
    "\n"
    "  -o, --output OUT   output directory (created if missing)\n"
    "  --info             print the file's header and arrays, then exit\n"
    "  --set KEY=VALUE    override a solver option stored in the file (e.g. --set "
    "max_iterations=50)\n"
    "  --threads N        shorthand for --set num_threads=N\n"
    "  --quiet            do not print the summary line\n"
    "\n"
    "exit codes: 0 ok, 1 usage, 2 bad input, 3 solve failed, 4 cannot write the outputs\n";

// Writes `text` into the temporary file `path`.tmp, flushed to the disk, and returns its name.
// On any failure (a full disk shows at write or fsync) the temporary file is removed and
// OutputError names `path` and the reason.
std::string WriteTemporary(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
  if (fd < 0) throw OutputError(path, errno);
  auto fail = [&](int error) {
    ::close(fd);
    ::unlink(tmp.c_str());
    throw OutputError(path, error);
  };
  size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) fail(n < 0 ? errno : ENOSPC);
    done += static_cast<size_t>(n);
  }
  if (::fsync(fd) != 0) fail(errno);
  if (::close(fd) != 0) {
    const int error = errno;
    ::unlink(tmp.c_str());
    throw OutputError(path, error);
  }
  return tmp;
}

// Writes every (path, text) pair as one set: all temporary files first, then the renames, so a
// failure (a full disk) leaves the earlier outputs as they were and no temporary file behind.
void WriteOutputs(const std::vector<std::pair<std::string, std::string>>& files) {
  std::vector<std::string> written;
  try {
    for (const auto& [path, text] : files) written.push_back(WriteTemporary(path, text));
    for (size_t i = 0; i < files.size(); ++i) {
      if (std::rename(written[i].c_str(), files[i].first.c_str()) != 0) {
        throw OutputError(files[i].first, errno);
      }
    }
  } catch (...) {
    for (const std::string& tmp : written) ::unlink(tmp.c_str());
    throw;
  }
}

std::string TumText(const bimcap::ProblemData& problem, const std::vector<double>& poses) {
  std::string text = "# timestamp tx ty tz qx qy qz qw (world_from_cam, refined by bimcap_solve)\n";
  char line[512];
  for (int64_t i = 0; i < problem.num_poses(); ++i) {
    const double* p = poses.data() + 7 * i;
    std::snprintf(line, sizeof(line), "%.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n",
                  problem.timestamps(i), p[0], p[1], p[2], p[3], p[4], p[5], p[6]);
    text += line;
  }
  return text;
}

// The command line. `exit_code` >= 0: stop with that code (help printed, or a usage error).
struct Args {
  std::string problem_path, output_dir;
  bool info = false, quiet = false;
  std::map<std::string, std::string> overrides;
  int exit_code = -1;
};

Args ParseArgs(int argc, char** argv) {
  Args a;
  auto stop = [&a](int code) {
    a.exit_code = code;
    return a;
  };
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto next = [&](const char* what) -> std::string {
      if (i + 1 >= argc) {
        std::cerr << "bimcap_solve: " << arg << " needs " << what << "\n" << kUsage;
        std::exit(kExitUsage);
      }
      return argv[++i];
    };
    if (arg == "-h" || arg == "--help") {
      std::cout << kUsage;
      return stop(0);
    } else if (arg == "-o" || arg == "--output") {
      a.output_dir = next("a directory");
    } else if (arg == "--info") {
      a.info = true;
    } else if (arg == "--quiet") {
      a.quiet = true;
    } else if (arg == "--threads") {
      a.overrides["num_threads"] = next("a number");
    } else if (arg == "--set") {
      const std::string kv = next("KEY=VALUE");
      const size_t eq = kv.find('=');
      if (eq == std::string::npos || eq == 0) {
        std::cerr << "bimcap_solve: --set expects KEY=VALUE, got '" << kv << "'\n";
        return stop(kExitUsage);
      }
      a.overrides[kv.substr(0, eq)] = kv.substr(eq + 1);
    } else if (!arg.empty() && arg[0] == '-') {
      std::cerr << "bimcap_solve: unknown option " << arg << "\n" << kUsage;
      return stop(kExitUsage);
    } else if (a.problem_path.empty()) {
      a.problem_path = arg;
    } else {
      std::cerr << "bimcap_solve: more than one problem file given\n" << kUsage;
      return stop(kExitUsage);
    }
  }
  if (a.problem_path.empty() || (!a.info && a.output_dir.empty())) {
    std::cerr << kUsage;
    return stop(kExitUsage);
  }
  return a;
}

// Read the problem file and apply the --set / --threads overrides; 0 or an exit code.
int LoadProblem(const Args& a, bimcap::ProblemFile* file, bimcap::SolverOptions* options) {
  try {
    *file = bimcap::ReadProblemFile(a.problem_path);
    if (a.info) return 0;
    auto values = bimcap::OptionsToKeyValues(file->options);
    for (const auto& [k, v] : a.overrides) {
      if (values.count(k) == 0) throw bimcap::OptionsError(k, "unknown option");
      values[k] = v;
    }
    *options = bimcap::OptionsFromKeyValues(values);
  } catch (const bimcap::InputError& e) {
    std::cerr << "bimcap_solve: error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "bimcap_solve: error: " << a.problem_path << ": " << e.what() << "\n";
    return kExitBadInput;
  }
  return 0;
}

// refined.tum and summary.json into `output_dir` (created); 0 or kExitOutput.
int WriteResult(const std::string& output_dir, const bimcap::ProblemFile& file,
                const bimcap::SolveResult& result) {
  try {
    if (::mkdir(output_dir.c_str(), 0777) != 0 && errno != EEXIST) {
      throw OutputError(output_dir, errno);
    }
    struct stat st;
    if (::stat(output_dir.c_str(), &st) != 0) throw OutputError(output_dir, errno);
    if (!S_ISDIR(st.st_mode)) throw OutputError(output_dir, ENOTDIR);
    WriteOutputs({{output_dir + "/refined.tum", TumText(file.problem, result.poses)},
                  {output_dir + "/summary.json", bimcap::SummaryToJson(result.summary)}});
  } catch (const std::exception& e) {
    std::cerr << "bimcap_solve: error: cannot write the outputs: " << e.what() << "\n";
    return kExitOutput;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const Args args = ParseArgs(argc, argv);
  if (args.exit_code >= 0) return args.exit_code;
  bimcap::ProblemFile file;
  bimcap::SolverOptions options;
  if (const int code = LoadProblem(args, &file, &options); code != 0) return code;
  if (args.info) {
    std::cout << bimcap::DescribeProblemFile(file);
    return 0;
  }

  bimcap::SolveResult result;
  try {
    result = bimcap::Solve(file.problem, options);
  } catch (const bimcap::InputError& e) {
    std::cerr << "bimcap_solve: error: " << args.problem_path << ": " << e.what() << "\n";
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::cerr << "bimcap_solve: solve failed: " << e.what() << "\n";
    return kExitSolveFailed;
  }
  if (const int code = WriteResult(args.output_dir, file, result); code != 0) return code;
  const bimcap::Summary& s = result.summary;
  if (!args.quiet) {
    std::cout << "bimcap_solve: " << s.termination << ", " << s.iterations << " iterations in "
              << s.outer_iterations << " rounds, cost " << s.initial_cost << " -> " << s.final_cost
              << ", " << s.time_s << " s\n";
  }
  if (!s.success) {
    std::cerr << "bimcap_solve: solve failed: " << s.message << "\n";
    return kExitSolveFailed;
  }
  return 0;
}
