#include "bimcap/options.h"

#include <gtest/gtest.h>

#include "bimcap/terms.h"

namespace bimcap {
namespace {

TEST(Options, DefaultsAreValidAndPaperWeights) {
  const SolverOptions o;
  EXPECT_NO_THROW(o.Check());
  EXPECT_EQ(o.term("geometric").paper_weight, 1.0);
  EXPECT_EQ(o.term("floor").paper_weight, 0.02);
  EXPECT_EQ(o.term("ceiling").paper_weight, 0.02);
  EXPECT_EQ(o.term("wall").paper_weight, 0.0007);
  EXPECT_EQ(o.term("column").paper_weight, 0.0007);
  // The pose prior: on, weak (2 m, 20°), plain L2, never in the paper objective.
  EXPECT_TRUE(o.term("prior").enabled);
  EXPECT_EQ(o.term("prior").paper_weight, 0.0);
  EXPECT_EQ(o.term("prior").sigma, 2.0);
  EXPECT_EQ(o.term("prior").param("sigma_r_deg"), 20.0);
  EXPECT_EQ(o.term("prior").loss, LossType::kNone);
  EXPECT_STREQ(TermName(TermIndex("prior")), "prior");
  EXPECT_EQ(&o.term(TermIndex("prior")), &o.term("prior"));
}

TEST(Options, TextRoundTrip) {
  SolverOptions o;
  o.weighting = Weighting::kPaper;
  o.geometric_mode = GeometricMode::kLandmark;
  o.term("wall").enabled = false;
  o.term("floor").loss = LossType::kCauchy;
  o.association_gate = 0.123456789;
  o.max_iterations = 17;
  o.term("prior").enabled = false;
  o.term("prior").sigma = 0.75;
  o.term("prior").params["sigma_r_deg"] = 3.5;
  const SolverOptions back = OptionsFromText(OptionsToText(o));
  EXPECT_EQ(OptionsToKeyValues(back), OptionsToKeyValues(o));
  EXPECT_EQ(back.association_gate, 0.123456789);
  EXPECT_FALSE(back.term("prior").enabled);
  EXPECT_EQ(back.term("prior").sigma, 0.75);
  EXPECT_EQ(back.term("prior").param("sigma_r_deg"), 3.5);
}

void ExpectRejected(const std::string& key, const std::string& value) {
  try {
    OptionsFromKeyValues({{key, value}});
    FAIL() << key << "=" << value << " was accepted";
  } catch (const OptionsError& e) {
    EXPECT_EQ(e.field(), key) << e.what();
  }
}

TEST(Options, BadValuesNameTheKey) {
  ExpectRejected("association_gate", "-1");
  ExpectRejected("association_gate", "nan");
  ExpectRejected("floor.sigma", "0");
  ExpectRejected("wall.loss", "L3");
  ExpectRejected("outer_iterations", "0");
  ExpectRejected("num_threads", "two");
  ExpectRejected("max_iterations", "1.5");
  ExpectRejected("geometric_mode", "POINTS");
  ExpectRejected("floor.enabled", "yes");
  ExpectRejected("no_such_option", "1");
  ExpectRejected("floor.no_such_field", "1");
  ExpectRejected("prior.paper_weight", "0.1");  // the prior is never part of the paper objective
  ExpectRejected("prior.sigma", "-2");
  ExpectRejected("prior.sigma_r_deg", "0");
  ExpectRejected("odometry.sigma_r_deg", "-1");
  EXPECT_THROW(OptionsFromText("weighting=PAPER\nweighting=ROBUST\n"), OptionsError);
  EXPECT_THROW(OptionsFromText("garbage line\n"), OptionsError);
}

TEST(Options, RenamedKeysOfOlderFilesAreStillRead) {
  const SolverOptions o =
      OptionsFromKeyValues({{"prior_sigma_r_deg", "7.5"}, {"odometry_sigma_r_deg", "3"}});
  EXPECT_EQ(o.term("prior").param("sigma_r_deg"), 7.5);
  EXPECT_EQ(o.term("odometry").param("sigma_r_deg"), 3.0);
  EXPECT_EQ(OptionsToKeyValues(o).count("prior_sigma_r_deg"), 0u);  // written under the new key
}

TEST(TermRegistry, EveryTermHasDistinctKeysAndItsArraysInTheFieldTable) {
  for (int t = 0; t < NumTerms(); ++t) {
    const TermSpec& spec = Terms()[t];
    EXPECT_EQ(TermIndex(spec.key), t) << spec.key;
    EXPECT_EQ(TermIndex(spec.name), t) << spec.name;
    EXPECT_NE(spec.validate, nullptr) << spec.key;
    EXPECT_NE(spec.add, nullptr) << spec.key;
    for (const ArraySpec& a : spec.arrays) {
      const FieldSpec* field = FindField(a.name);
      ASSERT_NE(field, nullptr) << a.name;
      EXPECT_EQ(field->dtype, a.dtype) << a.name;  // a shared array is declared alike
      EXPECT_EQ(field->cols, a.cols) << a.name;
    }
    EXPECT_EQ(SolverOptions().term(t).params.size(), spec.params.size()) << spec.key;
  }
  EXPECT_EQ(TermIndex("no such term"), -1);
  EXPECT_THROW(SolverOptions().term("no such term"), OptionsError);
}

TEST(Options, PresetsAreValidAndDiffer) {
  const SolverOptions robust = SolverOptions::Preset("robust");
  const SolverOptions paper = SolverOptions::Preset("paper");
  robust.Check();
  paper.Check();
  EXPECT_EQ(robust.weighting, Weighting::kRobust);
  EXPECT_EQ(robust.geometric_mode, GeometricMode::kReprojection);
  EXPECT_DOUBLE_EQ(robust.pixel_sigma, 2.0);
  EXPECT_DOUBLE_EQ(robust.term("floor").sigma, 0.05);
  EXPECT_DOUBLE_EQ(robust.term("depth").sigma, 0.02);
  EXPECT_EQ(robust.term("wall").loss, LossType::kCauchy);
  EXPECT_EQ(robust.term("depth").loss, LossType::kCauchy);
  EXPECT_EQ(robust.term("prior").loss, SolverOptions().term("prior").loss);
  EXPECT_EQ(paper.weighting, Weighting::kPaper);
  EXPECT_EQ(paper.geometric_mode, GeometricMode::kPoint);
  // A preset survives the text form.
  EXPECT_EQ(OptionsToText(OptionsFromText(OptionsToText(robust))), OptionsToText(robust));
  EXPECT_EQ(SolverOptions::PresetNames().size(), 2u);
}

TEST(Options, UnknownPresetNamesTheField) {
  try {
    SolverOptions::Preset("fast");
    FAIL() << "expected OptionsError";
  } catch (const OptionsError& e) {
    EXPECT_EQ(e.field(), "preset");
    EXPECT_NE(std::string(e.what()).find("robust"), std::string::npos);
  }
}

}  // namespace
}  // namespace bimcap
