#include "bimcap/options.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <sstream>

#include "bimcap/terms.h"

namespace bimcap {
namespace {

// Keys renamed since problem files were first written: old key → new key (read, never written).
const std::pair<const char*, const char*> kRenamedKeys[] = {
    {"prior_sigma_r_deg", "prior.sigma_r_deg"},
    {"odometry_sigma_r_deg", "odometry.sigma_r_deg"},
};

template <typename E>
struct EnumNames;
template <>
struct EnumNames<GeometricMode> {
  static std::vector<std::string> Get() { return {"POINT", "REPROJECTION", "LANDMARK"}; }
};
template <>
struct EnumNames<Weighting> {
  static std::vector<std::string> Get() { return {"PAPER", "ROBUST"}; }
};
template <>
struct EnumNames<LossType> {
  static std::vector<std::string> Get() {
    return {"NONE", "HUBER", "CAUCHY", "SOFT_L1", "ARCTAN", "TUKEY"};
  }
};
template <>
struct EnumNames<PlaneMode> {
  static std::vector<std::string> Get() { return {"BIM", "FACAP"}; }
};
template <>
struct EnumNames<RefineMode> {
  static std::vector<std::string> Get() { return {"FULL", "ROTATION", "TRANSLATION"}; }
};
template <>
struct EnumNames<LinearSolver> {
  static std::vector<std::string> Get() {
    return {"AUTO",        "DENSE_QR",     "DENSE_NORMAL_CHOLESKY", "SPARSE_NORMAL_CHOLESKY",
            "DENSE_SCHUR", "SPARSE_SCHUR", "ITERATIVE_SCHUR"};
  }
};

template <typename E>
std::string EnumToString(E e) {
  return EnumNames<E>::Get().at(static_cast<size_t>(e));
}

template <typename E>
E EnumFromString(const std::string& key, const std::string& value) {
  const auto names = EnumNames<E>::Get();
  for (size_t i = 0; i < names.size(); ++i) {
    if (names[i] == value) return static_cast<E>(i);
  }
  std::string allowed;
  for (const auto& n : names) allowed += (allowed.empty() ? "" : ", ") + n;
  throw OptionsError(key, "unknown value '" + value + "' (allowed: " + allowed + ")");
}

double ParseDouble(const std::string& key, const std::string& value) {
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(value.c_str(), &end);
  if (value.empty() || end != value.c_str() + value.size() || errno == ERANGE) {
    throw OptionsError(key, "not a number: '" + value + "'");
  }
  return v;
}

int ParseInt(const std::string& key, const std::string& value) {
  errno = 0;
  char* end = nullptr;
  const long v = std::strtol(value.c_str(), &end, 10);
  if (value.empty() || end != value.c_str() + value.size() || errno == ERANGE || v < -2147483647L ||
      v > 2147483647L) {
    throw OptionsError(key, "not an integer: '" + value + "'");
  }
  return static_cast<int>(v);
}

bool ParseBool(const std::string& key, const std::string& value) {
  if (value == "1" || value == "true" || value == "True") return true;
  if (value == "0" || value == "false" || value == "False") return false;
  throw OptionsError(key, "not a boolean (0/1): '" + value + "'");
}

std::string FormatDouble(double v) {
  std::ostringstream s;
  s.precision(17);
  s << v;
  return s.str();
}

void CheckPositive(const std::string& key, double v) {
  if (!(v > 0.0) || !std::isfinite(v)) {
    throw OptionsError(key, "must be a finite number > 0, got " + FormatDouble(v));
  }
}

void CheckNonNegative(const std::string& key, double v) {
  if (!(v >= 0.0) || !std::isfinite(v)) {
    throw OptionsError(key, "must be a finite number >= 0, got " + FormatDouble(v));
  }
}

}  // namespace

double TermOptions::param(std::string_view name) const {
  const auto it = params.find(name);
  if (it == params.end()) throw OptionsError(std::string(name), "no such term parameter");
  return it->second;
}

SolverOptions::SolverOptions() {
  for (const TermSpec& spec : Terms()) {
    terms.push_back(spec.defaults);
    for (const ParamSpec& param : spec.params)
      terms.back().params[param.name] = param.default_value;
  }
}

std::vector<std::string> SolverOptions::PresetNames() { return {"robust", "paper"}; }

SolverOptions SolverOptions::Preset(std::string_view name) {
  if (name != "robust" && name != "paper") {
    std::string allowed;
    for (const auto& n : PresetNames()) allowed += (allowed.empty() ? "" : ", ") + n;
    throw OptionsError("preset",
                       "unknown preset '" + std::string(name) + "' (allowed: " + allowed + ")");
  }
  SolverOptions o;
  o.weighting = Weighting::kRobust;
  o.geometric_mode = GeometricMode::kReprojection;
  o.pixel_sigma = 2.0;
  o.term("floor").sigma = 0.05;
  o.term("ceiling").sigma = 0.05;
  // Keypoint depths after planar smoothing: on the demo world their error against the
  // simulator's depth has a MAD of 0.5 cm and a 90th percentile of 2.2 cm.
  o.term("depth").sigma = 0.02;
  for (int t = 0; t < NumTerms(); ++t) {
    if (Terms()[t].paper_term) o.term(t).loss = LossType::kCauchy;
  }
  if (name == "paper") {
    o.weighting = Weighting::kPaper;
    o.geometric_mode = GeometricMode::kPoint;
  }
  return o;
}

TermOptions& SolverOptions::term(std::string_view key_or_name) {
  const int id = TermIndex(key_or_name);
  if (id < 0) throw OptionsError(std::string(key_or_name), "unknown term");
  return term(id);
}

const TermOptions& SolverOptions::term(std::string_view key_or_name) const {
  return const_cast<SolverOptions*>(this)->term(key_or_name);
}

void SolverOptions::Check() const {
  if (terms.size() != Terms().size()) {
    throw OptionsError("terms", "expected " + std::to_string(Terms().size()) + " terms, got " +
                                    std::to_string(terms.size()));
  }
  for (int t = 0; t < NumTerms(); ++t) {
    const TermSpec& spec = Terms()[t];
    const TermOptions& o = term(t);
    const std::string prefix = std::string(spec.key) + ".";
    CheckNonNegative(prefix + "paper_weight", o.paper_weight);
    CheckNonNegative(prefix + "weight", o.weight);
    CheckPositive(prefix + "sigma", o.sigma);
    CheckPositive(prefix + "loss_scale", o.loss_scale);
    if (static_cast<int>(o.loss) < 0 || static_cast<int>(o.loss) > 5) {
      throw OptionsError(prefix + "loss", "unknown loss");
    }
    if (!spec.paper_term && o.paper_weight != 0.0) {
      throw OptionsError(prefix + "paper_weight", std::string("must be 0: the ") + spec.what +
                                                      " is not part of the paper's objective");
    }
    for (const ParamSpec& param : spec.params) {
      const auto it = o.params.find(param.name);
      if (it == o.params.end()) throw OptionsError(prefix + param.name, "missing");
      CheckPositive(prefix + param.name, it->second);
    }
    if (o.params.size() != spec.params.size()) {
      throw OptionsError(prefix + "params", "unknown term parameter");
    }
  }
  CheckPositive("pixel_sigma", pixel_sigma);
  CheckPositive("association_gate", association_gate);
  if (outer_iterations < 1) throw OptionsError("outer_iterations", "must be >= 1");
  CheckNonNegative("association_change_tolerance", association_change_tolerance);
  CheckNonNegative("round_function_tolerance", round_function_tolerance);
  if (max_iterations < 0) throw OptionsError("max_iterations", "must be >= 0");
  CheckNonNegative("function_tolerance", function_tolerance);
  CheckNonNegative("gradient_tolerance", gradient_tolerance);
  CheckNonNegative("parameter_tolerance", parameter_tolerance);
  CheckPositive("max_time_s", max_time_s);
  if (num_threads < 1) throw OptionsError("num_threads", "must be >= 1");
  if (batch_size < 1) throw OptionsError("batch_size", "must be >= 1");
}

std::vector<std::string> OptionKeys() {
  std::vector<std::string> keys;
  for (const auto& kv : OptionsToKeyValues(SolverOptions())) keys.push_back(kv.first);
  return keys;
}

std::map<std::string, std::string> OptionsToKeyValues(const SolverOptions& o) {
  std::map<std::string, std::string> kv;
  kv["geometric_mode"] = EnumToString(o.geometric_mode);
  kv["weighting"] = EnumToString(o.weighting);
  kv["plane_mode"] = EnumToString(o.plane_mode);
  kv["refine_mode"] = EnumToString(o.refine_mode);
  for (int t = 0; t < NumTerms(); ++t) {
    const TermOptions& term = o.term(t);
    const std::string p = std::string(Terms()[t].key) + ".";
    kv[p + "enabled"] = term.enabled ? "1" : "0";
    kv[p + "paper_weight"] = FormatDouble(term.paper_weight);
    kv[p + "weight"] = FormatDouble(term.weight);
    kv[p + "sigma"] = FormatDouble(term.sigma);
    kv[p + "loss"] = EnumToString(term.loss);
    kv[p + "loss_scale"] = FormatDouble(term.loss_scale);
    for (const auto& [name, value] : term.params) kv[p + name] = FormatDouble(value);
  }
  kv["pixel_sigma"] = FormatDouble(o.pixel_sigma);
  kv["association_gate"] = FormatDouble(o.association_gate);
  kv["outer_iterations"] = std::to_string(o.outer_iterations);
  kv["association_change_tolerance"] = FormatDouble(o.association_change_tolerance);
  kv["round_function_tolerance"] = FormatDouble(o.round_function_tolerance);
  kv["max_iterations"] = std::to_string(o.max_iterations);
  kv["function_tolerance"] = FormatDouble(o.function_tolerance);
  kv["gradient_tolerance"] = FormatDouble(o.gradient_tolerance);
  kv["parameter_tolerance"] = FormatDouble(o.parameter_tolerance);
  kv["max_time_s"] = FormatDouble(o.max_time_s);
  kv["num_threads"] = std::to_string(o.num_threads);
  kv["batch_size"] = std::to_string(o.batch_size);
  kv["compress_batches"] = o.compress_batches ? "1" : "0";
  kv["linear_solver"] = EnumToString(o.linear_solver);
  kv["compute_covariance"] = o.compute_covariance ? "1" : "0";
  kv["verbose"] = o.verbose ? "1" : "0";
  return kv;
}

SolverOptions OptionsFromKeyValues(const std::map<std::string, std::string>& values) {
  SolverOptions o;
  for (const auto& [given_key, value] : values) {
    std::string key = given_key;
    for (const auto& [old_key, new_key] : kRenamedKeys) {
      if (key == old_key) key = new_key;
    }
    if (key == "geometric_mode") {
      o.geometric_mode = EnumFromString<GeometricMode>(key, value);
    } else if (key == "weighting") {
      o.weighting = EnumFromString<Weighting>(key, value);
    } else if (key == "plane_mode") {
      o.plane_mode = EnumFromString<PlaneMode>(key, value);
    } else if (key == "refine_mode") {
      o.refine_mode = EnumFromString<RefineMode>(key, value);
    } else if (key == "pixel_sigma") {
      o.pixel_sigma = ParseDouble(key, value);
    } else if (key == "association_gate") {
      o.association_gate = ParseDouble(key, value);
    } else if (key == "association_change_tolerance") {
      o.association_change_tolerance = ParseDouble(key, value);
    } else if (key == "round_function_tolerance") {
      o.round_function_tolerance = ParseDouble(key, value);
    } else if (key == "outer_iterations") {
      o.outer_iterations = ParseInt(key, value);
    } else if (key == "max_iterations") {
      o.max_iterations = ParseInt(key, value);
    } else if (key == "function_tolerance") {
      o.function_tolerance = ParseDouble(key, value);
    } else if (key == "gradient_tolerance") {
      o.gradient_tolerance = ParseDouble(key, value);
    } else if (key == "parameter_tolerance") {
      o.parameter_tolerance = ParseDouble(key, value);
    } else if (key == "max_time_s") {
      o.max_time_s = ParseDouble(key, value);
    } else if (key == "num_threads") {
      o.num_threads = ParseInt(key, value);
    } else if (key == "batch_size") {
      o.batch_size = ParseInt(key, value);
    } else if (key == "compress_batches") {
      o.compress_batches = ParseBool(key, value);
    } else if (key == "linear_solver") {
      o.linear_solver = EnumFromString<LinearSolver>(key, value);
    } else if (key == "compute_covariance") {
      o.compute_covariance = ParseBool(key, value);
    } else if (key == "verbose") {
      o.verbose = ParseBool(key, value);
    } else {
      bool found = false;
      for (int t = 0; t < NumTerms() && !found; ++t) {
        const std::string p = std::string(Terms()[t].key) + ".";
        if (key.compare(0, p.size(), p) != 0) continue;
        const std::string sub = key.substr(p.size());
        TermOptions& term = o.term(t);
        found = true;
        if (sub == "enabled") {
          term.enabled = ParseBool(key, value);
        } else if (sub == "paper_weight") {
          term.paper_weight = ParseDouble(key, value);
        } else if (sub == "weight") {
          term.weight = ParseDouble(key, value);
        } else if (sub == "sigma") {
          term.sigma = ParseDouble(key, value);
        } else if (sub == "loss") {
          term.loss = EnumFromString<LossType>(key, value);
        } else if (sub == "loss_scale") {
          term.loss_scale = ParseDouble(key, value);
        } else if (term.params.count(sub) != 0) {
          term.params[sub] = ParseDouble(key, value);
        } else {
          found = false;
        }
      }
      if (!found) throw OptionsError(key, "unknown option");
    }
  }
  o.Check();
  return o;
}

std::vector<OptionSpec> OptionSpecs() {
  const std::map<std::string, std::vector<std::string>> enums = {
      {"geometric_mode", EnumNames<GeometricMode>::Get()},
      {"weighting", EnumNames<Weighting>::Get()},
      {"plane_mode", EnumNames<PlaneMode>::Get()},
      {"refine_mode", EnumNames<RefineMode>::Get()},
      {"linear_solver", EnumNames<LinearSolver>::Get()},
      {"loss", EnumNames<LossType>::Get()},
  };
  const std::vector<std::string> ints = {"outer_iterations", "max_iterations", "num_threads",
                                         "batch_size"};
  std::vector<OptionSpec> out;
  for (const auto& [key, value] : OptionsToKeyValues(SolverOptions())) {
    const std::string leaf = key.substr(key.find('.') == std::string::npos ? 0 : key.find('.') + 1);
    OptionSpec spec{key, "float", value, {}};
    if (enums.count(leaf)) {
      spec.kind = "enum";
      spec.choices = enums.at(leaf);
    } else if (leaf == "enabled" || leaf == "compute_covariance" || leaf == "verbose" ||
               leaf == "compress_batches") {
      spec.kind = "bool";
    } else if (std::find(ints.begin(), ints.end(), leaf) != ints.end()) {
      spec.kind = "int";
    }
    out.push_back(spec);
  }
  return out;
}

std::string OptionsToText(const SolverOptions& options) {
  std::string text;
  for (const auto& [k, v] : OptionsToKeyValues(options)) text += k + "=" + v + "\n";
  return text;
}

SolverOptions OptionsFromText(const std::string& text) {
  std::map<std::string, std::string> kv;
  std::istringstream in(text);
  std::string line;
  int lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    if (line.empty() || line[0] == '#') continue;
    const size_t eq = line.find('=');
    if (eq == std::string::npos || eq == 0) {
      throw OptionsError("options", "line " + std::to_string(lineno) + " is not key=value");
    }
    const std::string key = line.substr(0, eq);
    if (kv.count(key)) throw OptionsError(key, "given twice");
    kv[key] = line.substr(eq + 1);
  }
  return OptionsFromKeyValues(kv);
}

}  // namespace bimcap
