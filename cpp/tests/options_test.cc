#include <gtest/gtest.h>

#include "bimcap/options.h"

namespace bimcap {
namespace {

TEST(Options, DefaultsAreValidAndPaperWeights) {
  const SolverOptions o;
  EXPECT_NO_THROW(o.Check());
  EXPECT_EQ(o.geometric.paper_weight, 1.0);
  EXPECT_EQ(o.floor.paper_weight, 0.02);
  EXPECT_EQ(o.ceiling.paper_weight, 0.02);
  EXPECT_EQ(o.wall.paper_weight, 0.0007);
  EXPECT_EQ(o.column.paper_weight, 0.0007);
  // The pose prior: on, weak (2 m, 20°), plain L2, never in the paper objective.
  EXPECT_TRUE(o.prior.enabled);
  EXPECT_EQ(o.prior.paper_weight, 0.0);
  EXPECT_EQ(o.prior.sigma, 2.0);
  EXPECT_EQ(o.prior_sigma_r_deg, 20.0);
  EXPECT_EQ(o.prior.loss, LossType::kNone);
  EXPECT_STREQ(TermName(kTermPrior), "prior");
  EXPECT_EQ(&o.term(kTermPrior), &o.prior);
}

TEST(Options, TextRoundTrip) {
  SolverOptions o;
  o.weighting = Weighting::kPaper;
  o.geometric_mode = GeometricMode::kLandmark;
  o.wall.enabled = false;
  o.floor.loss = LossType::kCauchy;
  o.association_gate = 0.123456789;
  o.max_iterations = 17;
  o.prior.enabled = false;
  o.prior.sigma = 0.75;
  o.prior_sigma_r_deg = 3.5;
  const SolverOptions back = OptionsFromText(OptionsToText(o));
  EXPECT_EQ(OptionsToKeyValues(back), OptionsToKeyValues(o));
  EXPECT_EQ(back.association_gate, 0.123456789);
  EXPECT_FALSE(back.prior.enabled);
  EXPECT_EQ(back.prior.sigma, 0.75);
  EXPECT_EQ(back.prior_sigma_r_deg, 3.5);
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
  ExpectRejected("prior_sigma_r_deg", "0");
  EXPECT_THROW(OptionsFromText("weighting=PAPER\nweighting=ROBUST\n"), OptionsError);
  EXPECT_THROW(OptionsFromText("garbage line\n"), OptionsError);
}

}  // namespace
}  // namespace bimcap
