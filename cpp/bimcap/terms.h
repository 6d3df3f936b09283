// The term registry: one TermSpec per residual term. Everything that depends on the set of terms
// reads it: the options (keys, defaults, Check), the problem's field table and validation, the
// builder, the solver's association and summary, the problem file, the Python binding, and
// through `bimcap._core.terms()` the Python side (Problem, SolverOptions, the schedule, the
// experiment rows). Adding a term: its functor header, its file in bimcap/terms/ (the spec, its
// validation and the function that adds its residuals), one line in terms.cc, a test
// (docs/adding-a-term.md).
#ifndef BIMCAP_TERMS_H_
#define BIMCAP_TERMS_H_

#include <cstdint>
#include <string_view>
#include <vector>

#include "bimcap/options.h"
#include "bimcap/problem.h"

namespace bimcap {

class ProblemBuilder;

// A problem array a term reads: name, dtype, number of columns (0 for a 1-D array).
struct ArraySpec {
  const char* name;
  DType dtype;
  int cols;
};

// A per-term scalar option beyond TermOptions' six, e.g. the pose prior's rotation scale; its
// key is "<term key>.<name>"; it must be a finite number > 0.
struct ParamSpec {
  const char* name;
  double default_value;
  const char* doc;
};

struct TermSpec {
  const char* name;  // in summaries and term lists: "G", "F", "prior" ...
  const char* key;   // option prefix ("floor.sigma"), association and FACaP plane name
  const char* what;  // in messages: "floor"
  const char* doc;   // one line: the residual and its unit
  // One of the paper's terms: switched by `with_terms`, part of the peers' objective. Other
  // terms (the pose prior, the odometry) act in ROBUST weighting only, with paper_weight 0.
  bool paper_term;
  // Ties poses to the BIM (F, Ce, W, Co): the terms of the schedule's BIM-only stage.
  bool bim_term;
  TermOptions defaults;
  std::vector<ArraySpec> arrays;
  std::vector<ParamSpec> params;
  // > 0: the term's points (`<points>_frame`, `<points>_p_in_cam`) are associated with the
  // floor-plan segments of this class (re-associated between Ceres runs).
  int32_t segment_class = 0;
  // FACaP plane mode: one free plane is fitted to the term's points.
  bool facap_plane = false;
  // Prefix of the term's per-point arrays, for association and the FACaP fit ("" for none).
  const char* points = "";
  // Checks the term's arrays (shapes, indices, finiteness); throws ProblemError naming the
  // array. Called after the core arrays are checked.
  void (*validate)(const ProblemData& problem);
  // Adds the term's residual blocks (see ProblemBuilder's public interface).
  void (*add)(ProblemBuilder& builder, int term);
};

// Every term, in summary order.
const std::vector<TermSpec>& Terms();
int NumTerms();
// The index of the term with this key ("floor") or name ("F"), or -1.
int TermIndex(std::string_view key_or_name);
const char* TermName(int term);  // "?" when out of range

}  // namespace bimcap

#endif  // BIMCAP_TERMS_H_
