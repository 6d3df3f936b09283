// Several observations of one term that share their parameter blocks (a frame's floor points,
// the matches of one frame pair ...) in one residual block, with the term's robust loss applied
// to each observation.
#ifndef BIMCAP_COST_FUNCTIONS_BATCHED_H_
#define BIMCAP_COST_FUNCTIONS_BATCHED_H_

#include <ceres/cost_function.h>
#include <ceres/loss_function.h>
#include <ceres/manifold.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <utility>
#include <vector>

#include "bimcap/cost_functions/pose_tangent.h"
#include "bimcap/cost_functions/reprojection.h"
#include "bimcap/pose.h"

namespace bimcap {

// The observations i = 1..n of a term whose cost functions take the same parameter blocks, each
// with raw residual r_i (k values, the term's whitening and weight inside) and Jacobian J_i,
// in one residual block. Ceres applies a loss to the squared norm of a whole block, so the
// block carries no Ceres loss: the term's loss ρ acts on each observation here, as Ceres would
// on a block of its own (its Corrector, Triggs et al.'s correction), and one last residual
// carries the rest of the robust cost:
//
//   s_i = ‖r_i‖²,   ρ_i = ρ(s_i), ρ′_i, ρ″_i
//   α_i = 1 − √(1 + 2 s_i ρ″_i / ρ′_i)   where s_i > 0 and ρ″_i > 0, else α_i = 0
//   r̃_i = √ρ′_i / (1 − α_i) · r_i                                             (k rows)
//   J̃_i = √ρ′_i · (I − α_i r_i r_iᵀ / s_i) · J_i
//   t   = √( Σ_i (ρ_i − ‖r̃_i‖²) )                     (the last row; its Jacobian row is 0)
//
// So ½‖[r̃; t]‖² = ½ Σ_i ρ(s_i), the cost of one block per observation with the loss ρ, the
// gradient J̃ᵀ r̃ = Σ_i ρ′_i J_iᵀ r_i is its gradient, and J̃ᵀJ̃ its Gauss-Newton matrix: the
// trust-region model and step, and the cost the step acceptance sees, are those Ceres builds for
// the per-observation form (to rounding). ρ_i − ‖r̃_i‖² = ρ_i − ρ′_i s_i ≥ 0 for every loss
// with ρ″ ≤ 0 (Huber, Cauchy, soft-L1, arctan, Tukey); it is clamped at 0 otherwise. Without a
// loss the block is the n·k rows r̃_i = r_i, J̃_i = J_i (no last row).
//
// Row form: the per-observation cost functions (owned) are evaluated one after the other into
// their rows of the block's residuals and Jacobians (row-major, rows × block size): n·k + 1
// rows.
//
// Compressed form (the default once n·k > T). All that Ceres' trust-region step uses of a block
// is its cost, the Gauss-Newton matrix and gradient in the tangent space of its parameter blocks
// and their column norms; its linear solver forms that matrix row by row, after multiplying each
// row by the manifolds' Plus Jacobians P_b (ambient × tangent). With T = Σ_b tangent sizes (6 for
// one pose, 12 for two), the block is T + 1 rows instead, made from the same r̃_i and the
// tangent Jacobians J̃_i P of the parameter blocks Ceres asks for (P = diag P_b):
//
//   H = Σ_i (J̃_i P)ᵀ (J̃_i P) (T × T),   g = Σ_i (J̃_i P)ᵀ r̃_i,   c = Σ_i ρ_i (Σ_i s_i without a
//   loss) S⁻¹ H S⁻¹ ≈ Πᵀ L Lᵀ Π    (S = diag √H_aa; Cholesky with diagonal pivoting, rank m: pivots
//                             ≤ 1e-12 of the equilibrated H, directions H does not see, dropped)
//   R = Lᵀ Π S   (m × T),   z = L⁻¹ Π S⁻¹ g   (so Rᵀ R = H and Rᵀ z = g)
//   rows: z (m values), zeros up to T, then t = √(c − ‖z‖²)        (the last row's Jacobian is 0)
//   ambient Jacobian of block b: R_b P_b⁺,   P_b⁺ = (P_bᵀ P_b)⁻¹ P_bᵀ  (so Ceres' R_b P_b⁺ P_b =
//   R_b)
//
// So Ceres sees the same cost, tangent gradient, Gauss-Newton matrix and column norms (hence the
// same Levenberg-Marquardt diagonal and Jacobi scaling), to rounding, from T + 1 rows instead of
// n·k + 1. The factorisation is in the tangent space: a direction a term does not see stays
// empty there (compressing the 7-vector ambient Jacobians instead leaked rounding into such
// directions). A residual-only evaluation (Ceres' candidate points read the cost only) writes
// [0, ..., 0, √c]. Constant parameter blocks (a null jacobians[b]) are left out of H and g.
//
// Relative form (a compressed batch of G's reprojections, AddReprojection, on two full poses
// a, b: each depends on b⁻¹ a alone). Each observation's
// Jacobian is J̃_i [E_ab, I] with J̃_i its k × 6 Jacobian in pose b's tangent (pose.h:
// RelativeTangentMap), so H and g are made on those 6 columns, H_b = Σ J̃_iᵀ J̃_i and
// g_b = Σ J̃_iᵀ r̃_i, and factorised as above into R_b (m × 6, m ≤ 6) and z; the rows are z,
// zeros up to 6, then t (7 rows instead of 13), with tangent Jacobians R_b E_ab for pose a and
// R_b for pose b, so that Ceres sees [E_ab, I]ᵀ H_b [E_ab, I] = H and [E_ab, I]ᵀ g_b = g: the
// same model, built from a third of the products an observation (2 × 6 Jacobians, 6 × 6 sums),
// and summed in camera b's axes (EvaluateReprojectionInCameraB, RotatePoseModel).
//
// Observations come as cost functions (Add: each its own object, called through its vtable) or,
// for G's reprojections, as plain ReprojectionObservations that share one ReprojectionModel
// (AddReprojection: 40 bytes each, side by side, evaluated inline; the same operations as
// ReprojectionCostFunction's, so the same numbers bit for bit). A batch holds one kind.
class BatchedCostFunction final : public ceres::CostFunction {
 public:
  // `loss` (null: plain squares) must outlive the cost function; `residuals_per_sample` = k.
  // `manifolds`: the manifold of each parameter block, as the problem sets it (null or absent:
  // Euclidean; they must outlive the cost function); `compress`: the compressed form once
  // n·k > T (false: always the row form).
  BatchedCostFunction(const ceres::LossFunction* loss, int residuals_per_sample,
                      std::vector<const ceres::Manifold*> manifolds = {}, bool compress = true)
      : loss_(loss),
        k_(residuals_per_sample),
        manifolds_(std::move(manifolds)),
        compress_(compress) {}

  // Appends an observation (before the block goes into a problem); `index` is its position in
  // its term (for messages). All observations take the same parameter block sizes.
  void Add(std::unique_ptr<ceres::CostFunction> sample, int64_t index) {
    if (!reprojections_.empty())
      throw std::logic_error("BatchedCostFunction: a cost function in a batch of reprojections");
    if (samples_.empty()) {
      if (sample->num_residuals() != k_)
        throw std::logic_error("BatchedCostFunction: an observation of unexpected size");
      SetBlocks(sample->parameter_block_sizes());
    }
    pose_tangent_ =
        pose_tangent_ && dynamic_cast<const PoseTangentCostFunction*>(sample.get()) != nullptr;
    samples_.push_back(std::move(sample));
    Added(index);
  }

  // Appends one of G's reprojections on [world_from_cam_a, world_from_cam_b] (k = 2); every
  // observation of the batch shares `model`.
  void AddReprojection(const ReprojectionModel& model, const ReprojectionObservation& observation,
                       int64_t index) {
    if (!samples_.empty() || (!reprojections_.empty() && !(model == reprojection_model_)))
      throw std::logic_error("BatchedCostFunction: a reprojection of another kind or model");
    if (reprojections_.empty()) {
      if (k_ != 2) throw std::logic_error("BatchedCostFunction: a reprojection has 2 residuals");
      SetBlocks({kPoseSize, kPoseSize});
      relative_ = pose_tangent_;  // a reprojection depends on b⁻¹ a alone
      reprojection_model_ = model;
    }
    reprojections_.push_back(observation);
    Added(index);
  }

  bool compressed() const { return compressed_; }
  int num_samples() const { return static_cast<int>(indices_.size()); }
  int residuals_per_sample() const { return k_; }
  int64_t sample_index(int i) const { return indices_[i]; }
  // Observation i's raw residuals (k values: the term's whitening and weight, no loss) and, with
  // `jacobians`, its ambient Jacobians, as its own cost function gives them.
  bool EvaluateSample(int i, double const* const* parameters, double* residuals,
                      double** jacobians = nullptr) const {
    if (reprojections_.empty()) return samples_[i]->Evaluate(parameters, residuals, jacobians);
    return EvaluateReprojection(reprojection_model_, reprojections_[i], parameters[0],
                                parameters[1], residuals, jacobians);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    if (compressed_) return EvaluateCompressed(parameters, residuals, jacobians);
    const std::vector<int32_t>& sizes = parameter_block_sizes();
    const size_t num_blocks = sizes.size();
    const size_t n = indices_.size();
    double* sample_jacobians[kMaxBlocks];
    double rest = 0.0;  // Σ_i ρ_i − ‖r̃_i‖²
    for (size_t i = 0; i < n; ++i) {
      double* r = residuals + k_ * i;
      for (size_t b = 0; b < num_blocks; ++b) {
        sample_jacobians[b] = (jacobians != nullptr && jacobians[b] != nullptr)
                                  ? jacobians[b] + static_cast<size_t>(k_) * i * sizes[b]
                                  : nullptr;
      }
      if (!EvaluateSample(static_cast<int>(i), parameters, r,
                          jacobians != nullptr ? sample_jacobians : nullptr))
        return false;
      if (loss_ == nullptr) continue;
      const Correction c = Corrector(r);
      for (size_t b = 0; jacobians != nullptr && b < num_blocks; ++b) {
        if (sample_jacobians[b] != nullptr) CorrectJacobian(c, r, sample_jacobians[b], sizes[b]);
      }
      for (int row = 0; row < k_; ++row) r[row] *= c.residual_scaling;
      rest += c.rho - c.residual_scaling * c.residual_scaling * c.s;
    }
    if (loss_ == nullptr) return true;
    residuals[k_ * n] = std::sqrt(std::max(rest, 0.0));
    if (jacobians != nullptr) {
      for (size_t b = 0; b < num_blocks; ++b) {
        if (jacobians[b] == nullptr) continue;
        std::fill_n(jacobians[b] + static_cast<size_t>(k_) * n * sizes[b], sizes[b], 0.0);
      }
    }
    return true;
  }

  static constexpr size_t kMaxBlocks = 8;  // parameter blocks per observation
  // The compressed form's bounds (beyond them a batch stays in the row form):
  static constexpr int kMaxK = 8;         // residuals per observation
  static constexpr int kMaxAmbient = 16;  // a parameter block's size
  static constexpr int kMaxCols = 32;     // Σ tangent sizes (T)

 private:
  // The first observation's parameter block sizes, and what they allow.
  void SetBlocks(const std::vector<int32_t>& sizes) {
    if (sizes.size() > kMaxBlocks || manifolds_.size() > sizes.size())
      throw std::logic_error("BatchedCostFunction: an observation of unexpected size");
    manifolds_.resize(sizes.size(), nullptr);
    tangent_cols_ = 0;
    // The compressed form's buffers are fixed: larger observations stay in the row form.
    bool fits = k_ <= kMaxK;
    for (size_t b = 0; b < sizes.size(); ++b) {
      const ceres::Manifold* m = manifolds_[b];
      if (m != nullptr && m->AmbientSize() != sizes[b])
        throw std::logic_error("BatchedCostFunction: a manifold of unexpected size");
      fits = fits && sizes[b] <= kMaxAmbient;
      tangent_cols_ += m != nullptr ? m->TangentSize() : sizes[b];
    }
    compress_ = compress_ && fits && tangent_cols_ <= kMaxCols;
    *mutable_parameter_block_sizes() = sizes;
    pose_tangent_ = true;
    for (const ceres::Manifold* m : manifolds_)
      pose_tangent_ = pose_tangent_ && IsFullPoseManifold(m);
  }

  // After an observation went in: its index, the form and the number of rows.
  void Added(int64_t index) {
    indices_.push_back(index);
    const int rows = k_ * num_samples();
    const int model_cols = relative_ ? kPoseTangentSize : tangent_cols_;
    compressed_ = compress_ && rows > model_cols;
    set_num_residuals(compressed_ ? model_cols + 1 : rows + (loss_ != nullptr ? 1 : 0));
  }

  // Ceres' Corrector of one observation (internal/ceres/corrector.cc), from its raw residuals.
  struct Correction {
    double s = 0.0;    // ‖r‖²
    double rho = 0.0;  // ρ(s); s without a loss
    double sqrt_rho1 = 1.0;
    double alpha_sq_norm = 0.0;  // α / s
    double residual_scaling = 1.0;
  };

  Correction Corrector(const double* r) const {
    Correction c;
    for (int row = 0; row < k_; ++row) c.s += r[row] * r[row];
    c.rho = c.s;
    if (loss_ == nullptr) return c;
    double rho[3];
    loss_->Evaluate(c.s, rho);
    c.rho = rho[0];
    c.sqrt_rho1 = std::sqrt(rho[1]);
    c.residual_scaling = c.sqrt_rho1;
    if (c.s > 0.0 && rho[2] > 0.0) {
      const double alpha = 1.0 - std::sqrt(1.0 + 2.0 * c.s * rho[2] / rho[1]);
      c.residual_scaling = c.sqrt_rho1 / (1.0 - alpha);
      c.alpha_sq_norm = alpha / c.s;
    }
    return c;
  }

  // J̃ = √ρ′ (I − α r rᵀ / s) J in place, for the k × cols row-major `j` and the raw `r`.
  void CorrectJacobian(const Correction& c, const double* r, double* j, int cols) const {
    for (int col = 0; col < cols; ++col) {
      double rt_j = 0.0;
      if (c.alpha_sq_norm != 0.0) {
        for (int row = 0; row < k_; ++row) rt_j += r[row] * j[row * cols + col];
      }
      for (int row = 0; row < k_; ++row) {
        j[row * cols + col] = c.sqrt_rho1 * (j[row * cols + col] - c.alpha_sq_norm * r[row] * rt_j);
      }
    }
  }

  // The compressed form (see the class comment).
  bool EvaluateCompressed(double const* const* parameters, double* residuals,
                          double** jacobians) const;

  const ceres::LossFunction* loss_;
  const int k_;
  std::vector<const ceres::Manifold*> manifolds_;
  bool compress_;            // asked for, and the observations fit the compressed form's buffers
  int tangent_cols_ = 0;     // T
  bool compressed_ = false;  // n·k > T and compress_
  // Every observation a PoseTangentCostFunction and every block on the kFull pose manifold: the
  // compressed form takes the observations' tangent Jacobians from EvaluateTangent.
  bool pose_tangent_ = false;
  // G's reprojections on two full poses: the compressed form's model is built on pose b's 6
  // columns (EvaluateReprojectionInCameraB) and mapped to pose a by E_ab.
  bool relative_ = false;
  std::vector<std::unique_ptr<ceres::CostFunction>> samples_;  // observations as cost functions
  std::vector<ReprojectionObservation> reprojections_;         // or as G's reprojections
  ReprojectionModel reprojection_model_;
  std::vector<int64_t> indices_;
};

namespace batched_internal {

// H += Σ_rows jᵀ j (lower triangle of the cols × cols row-major h), g += Σ_rows jᵀ r over the
// k × cols row-major j; K, C > 0 fix k and cols at compile time.
template <int K, int C>
inline void Accumulate(const double* j, const double* r, double* h, double* g, int k = K,
                       int cols = C) {
  if constexpr (K > 0) k = K;
  if constexpr (C > 0) cols = C;
  for (int row = 0; row < k; ++row) {
    const double* jr = j + row * cols;
    for (int a = 0; a < cols; ++a) {
      g[a] += jr[a] * r[row];
      double* ha = h + a * cols;
      for (int c = 0; c <= a; ++c) ha[c] += jr[a] * jr[c];
    }
  }
}

// out (k × t, row stride `stride`) = j (k × a, row-major) · plus (a × t, row-major); A, T > 0 fix
// a and t at compile time.
template <int A, int T>
inline void ToTangent(const double* j, const double* plus, int k, double* out, int stride,
                      int a = A, int t = T) {
  if constexpr (A > 0) a = A;
  if constexpr (T > 0) t = T;
  for (int row = 0; row < k; ++row) {
    for (int c = 0; c < t; ++c) {
      double v = 0.0;
      for (int x = 0; x < a; ++x) v += j[row * a + x] * plus[x * t + c];
      out[row * stride + c] = v;
    }
  }
}

// A 6 × 6 model (h: row-major, lower triangle; g) on [δt, δθ] in a camera's axes, turned into
// the pose's: H = D H_c Dᵀ, g = D g_c with D = diag(R, R) (R: world_from_cam's rotation).
inline void RotatePoseModel(const Eigen::Matrix3d& rotation, double* h, double* g) {
  Eigen::Matrix<double, 6, 6> full;
  for (int a = 0; a < 6; ++a) {
    for (int c = 0; c <= a; ++c) full(a, c) = full(c, a) = h[a * 6 + c];
  }
  Eigen::Matrix<double, 6, 6> d = Eigen::Matrix<double, 6, 6>::Zero();
  d.topLeftCorner<3, 3>() = rotation;
  d.bottomRightCorner<3, 3>() = rotation;
  const Eigen::Matrix<double, 6, 6> turned = d * full * d.transpose();
  Eigen::Map<Eigen::Matrix<double, 6, 1>> g_map(g);
  const Eigen::Matrix<double, 6, 1> g_turned = d * g_map;
  g_map = g_turned;
  for (int a = 0; a < 6; ++a) {
    for (int c = 0; c <= a; ++c) h[a * 6 + c] = turned(a, c);
  }
}

}  // namespace batched_internal

inline bool BatchedCostFunction::EvaluateCompressed(double const* const* parameters,
                                                    double* residuals, double** jacobians) const {
  using batched_internal::Accumulate;
  using batched_internal::ToTangent;
  const std::vector<int32_t>& sizes = parameter_block_sizes();
  const size_t num_blocks = sizes.size();
  const int rows = (relative_ ? kPoseTangentSize : tangent_cols_) + 1;
  // The blocks whose Jacobian is asked for, their first tangent column and Plus Jacobian.
  int first[kMaxBlocks], tangent[kMaxBlocks];
  double plus[kMaxBlocks][kMaxAmbient * kMaxAmbient];
  double block_j[kMaxBlocks][kMaxK * kMaxAmbient];  // observation i's ambient Jacobians
  double* sample_jacobians[kMaxBlocks];
  int cols = 0;
  for (size_t b = 0; b < num_blocks; ++b) {
    const bool wanted = jacobians != nullptr && jacobians[b] != nullptr;
    const ceres::Manifold* m = manifolds_[b];
    first[b] = wanted ? cols : -1;
    tangent[b] = m != nullptr ? m->TangentSize() : sizes[b];
    sample_jacobians[b] = wanted ? block_j[b] : nullptr;
    if (!wanted) continue;
    cols += tangent[b];
    if (m != nullptr && !m->PlusJacobian(parameters[b], plus[b])) return false;
  }
  // The model's columns: the wanted blocks' tangent columns, or with relative_ pose b's 6 (the
  // model of b⁻¹ a, mapped to the wanted blocks at the end).
  const int hc = relative_ && cols > 0 ? kPoseTangentSize : cols;
  double r[kMaxK];
  double j[kMaxK * kMaxCols];     // observation i's tangent Jacobian, k × hc row-major
  double h[kMaxCols * kMaxCols];  // hc × hc row-major, lower triangle used
  double g[kMaxCols];
  std::fill_n(h, hc * hc, 0.0);
  std::fill_n(g, hc, 0.0);
  double total = 0.0;
  // With pose_tangent_: the poses as matrices, and each observation's k × 6·blocks Jacobian.
  PoseMatrix poses[kMaxBlocks];
  double pose_j[kMaxK * kPoseTangentSize * kMaxBlocks];
  const int pose_cols = kPoseTangentSize * static_cast<int>(num_blocks);
  if (pose_tangent_) {
    for (size_t b = 0; b < num_blocks; ++b) poses[b] = PoseMatrix::FromBlock(parameters[b]);
  }
  // Observation i's loss, cost and share of H and g, from its raw residuals r and (cols > 0)
  // its tangent Jacobian: in j already (relative_), in pose_j (pose_tangent_), else in block_j.
  // Inlined into each of the three loops below (without it the 1000-frame solve is ~6 % slower:
  // 3.79-3.81 against 4.01-4.05 s in four alternating pairs).
  const auto add_to_model = [&]() __attribute__((always_inline)) {
    const Correction c = Corrector(r);
    total += c.rho;
    if (cols == 0) return;
    for (size_t b = 0; b < num_blocks && !relative_; ++b) {
      if (first[b] < 0) continue;
      if (pose_tangent_) {
        for (int row = 0; row < k_; ++row) {
          std::copy_n(pose_j + row * pose_cols + kPoseTangentSize * b, kPoseTangentSize,
                      j + row * cols + first[b]);
        }
      } else if (manifolds_[b] == nullptr) {
        for (int row = 0; row < k_; ++row) {
          std::copy_n(block_j[b] + row * sizes[b], sizes[b], j + row * cols + first[b]);
        }
      } else if (sizes[b] == 7 && tangent[b] == 6) {
        ToTangent<7, 6>(block_j[b], plus[b], k_, j + first[b], cols);
      } else {
        ToTangent<0, 0>(block_j[b], plus[b], k_, j + first[b], cols, sizes[b], tangent[b]);
      }
    }
    if (loss_ != nullptr) {
      CorrectJacobian(c, r, j, hc);
      for (int row = 0; row < k_; ++row) r[row] *= c.residual_scaling;
    }
    // The usual sizes with compile-time bounds (unrolled), else the same loops at run time.
    if (k_ == 1 && hc == 6) {
      Accumulate<1, 6>(j, r, h, g);
    } else if (k_ == 2 && hc == 6) {
      Accumulate<2, 6>(j, r, h, g);
    } else if (k_ == 1 && hc == 12) {
      Accumulate<1, 12>(j, r, h, g);
    } else if (k_ == 2 && hc == 12) {
      Accumulate<2, 12>(j, r, h, g);
    } else {
      Accumulate<0, 0>(j, r, h, g, k_, hc);
    }
  };
  if (relative_) {
    // G's reprojections, inline, on b⁻¹ a: the model in camera b's axes, H_c and g_c, then
    // turned into pose b's tangent, H = D H_c Dᵀ and g = D g_c with D = diag(R_b, R_b).
    const RelativePose b_from_a = RelativePose::Between(poses[0], poses[1]);
    for (const ReprojectionObservation& observation : reprojections_) {
      EvaluateReprojectionInCameraB(reprojection_model_, observation, b_from_a, r,
                                    hc > 0 ? j : nullptr);
      add_to_model();
    }
    if (hc > 0) batched_internal::RotatePoseModel(poses[1].rotation, h, g);
  } else if (!reprojections_.empty()) {
    // Not on full pose manifolds: the ambient Jacobians.
    for (const ReprojectionObservation& observation : reprojections_) {
      EvaluateReprojection(reprojection_model_, observation, parameters[0], parameters[1], r,
                           cols > 0 ? sample_jacobians : nullptr);
      add_to_model();
    }
  } else {
    for (const auto& sample : samples_) {
      if (pose_tangent_) {
        const auto* tangent_sample = static_cast<const PoseTangentCostFunction*>(sample.get());
        if (!tangent_sample->EvaluateTangent(poses, r, cols > 0 ? pose_j : nullptr)) return false;
      } else if (!sample->Evaluate(parameters, r, cols > 0 ? sample_jacobians : nullptr)) {
        return false;
      }
      add_to_model();
    }
  }
  std::fill_n(residuals, rows, 0.0);
  if (cols == 0) {
    residuals[rows - 1] = std::sqrt(std::max(total, 0.0));
    return true;
  }
  // Equilibrated: H' = S⁻¹ H S⁻¹, g' = S⁻¹ g with S = diag √H_aa (an empty column stays 0), so
  // that the factorisation's rounding is relative to each column's own scale, as in JᵀJ.
  double scale[kMaxCols], inv_scale[kMaxCols];
  for (int a = 0; a < hc; ++a) {
    scale[a] = std::sqrt(h[a * hc + a]);
    inv_scale[a] = scale[a] > 0.0 ? 1.0 / scale[a] : 0.0;
  }
  for (int a = 0; a < hc; ++a) {
    g[a] *= inv_scale[a];
    for (int c = 0; c <= a; ++c) h[a * hc + c] *= inv_scale[a] * inv_scale[c];
  }
  // Cholesky with diagonal pivoting of H', in place (lower triangle): Π H' Πᵀ = L Lᵀ.
  int perm[kMaxCols];
  for (int a = 0; a < hc; ++a) perm[a] = a;
  constexpr double kPivotTolerance = 1e-12;
  auto at = [&](int a, int c) -> double& { return a >= c ? h[a * hc + c] : h[c * hc + a]; };
  int rank = 0;
  for (; rank < hc; ++rank) {
    const int k = rank;
    int p = k;
    for (int a = k + 1; a < hc; ++a) {
      if (at(a, a) > at(p, p)) p = a;
    }
    if (!(at(p, p) > kPivotTolerance)) break;
    if (p != k) {
      for (int c = 0; c < hc; ++c) {
        if (c != k && c != p) std::swap(at(k, c), at(p, c));
      }
      std::swap(at(k, k), at(p, p));
      std::swap(perm[k], perm[p]);
    }
    const double lkk = std::sqrt(at(k, k));
    at(k, k) = lkk;
    for (int a = k + 1; a < hc; ++a) at(a, k) /= lkk;
    for (int a = k + 1; a < hc; ++a) {
      for (int c = k + 1; c <= a; ++c) at(a, c) -= at(a, k) * at(c, k);
    }
  }
  // z = L⁻¹ Π g' (forward substitution over the rank rows).
  double z_sq = 0.0;
  for (int k = 0; k < rank; ++k) {
    double v = g[perm[k]];
    for (int c = 0; c < k; ++c) v -= at(k, c) * residuals[c];
    residuals[k] = v / at(k, k);
    z_sq += residuals[k] * residuals[k];
  }
  residuals[rows - 1] = std::sqrt(std::max(total - z_sq, 0.0));
  // R = Lᵀ Π S (rank × hc): R(k, perm[a]) = L(a, k) S_perm[a] for a ≥ k. The wanted blocks'
  // tangent rows `tangent_rows` (rank × cols): R itself, or with relative_ R for pose b and
  // R E_ab for pose a. Then block b's ambient rows R_b P_b⁺.
  double model_rows[kMaxCols * kMaxCols];
  std::fill_n(model_rows, rank * hc, 0.0);
  for (int k = 0; k < rank; ++k) {
    for (int a = k; a < hc; ++a) model_rows[k * hc + perm[a]] = at(a, k) * scale[perm[a]];
  }
  double relative_rows[kMaxCols * kPoseTangentSize];
  const double* tangent_rows = model_rows;
  if (relative_) {
    const Eigen::Vector3d d = poses[0].translation - poses[1].translation;  // t_a − t_b
    for (int k = 0; k < rank; ++k) {
      const double* row_b = model_rows + k * hc;
      double* out = relative_rows + k * cols;
      if (first[0] >= 0) RelativeTangentMap(d, row_b, 1, kPoseTangentSize, out + first[0]);
      if (first[1] >= 0) std::copy_n(row_b, kPoseTangentSize, out + first[1]);
    }
    tangent_rows = relative_rows;
  }
  double r_row[kMaxCols];
  for (size_t b = 0; b < num_blocks; ++b) {
    if (first[b] < 0) continue;
    const int a_size = sizes[b], t_size = tangent[b];
    double* jb = jacobians[b];
    std::fill_n(jb, static_cast<size_t>(rows) * a_size, 0.0);
    // (P_bᵀ P_b) = M M_ᵀ by Cholesky, for P_b⁺ = (P_bᵀ P_b)⁻¹ P_bᵀ.
    const ceres::Manifold* m = manifolds_[b];
    double gram[kMaxAmbient * kMaxAmbient];
    if (m != nullptr) {
      const double* pb = plus[b];
      for (int x = 0; x < t_size; ++x) {
        for (int y = 0; y <= x; ++y) {
          double v = 0.0;
          for (int a = 0; a < a_size; ++a) v += pb[a * t_size + x] * pb[a * t_size + y];
          gram[x * t_size + y] = v;
        }
      }
      for (int x = 0; x < t_size; ++x) {
        for (int y = 0; y < x; ++y)
          gram[x * t_size + x] -= gram[x * t_size + y] * gram[x * t_size + y];
        if (!(gram[x * t_size + x] > 0.0)) return false;
        gram[x * t_size + x] = std::sqrt(gram[x * t_size + x]);
        for (int w = x + 1; w < t_size; ++w) {
          double v = gram[w * t_size + x];
          for (int y = 0; y < x; ++y) v -= gram[w * t_size + y] * gram[x * t_size + y];
          gram[w * t_size + x] = v / gram[x * t_size + x];
        }
      }
    }
    for (int k = 0; k < rank; ++k) {
      std::copy_n(tangent_rows + k * cols + first[b], t_size, r_row);
      double* out = jb + static_cast<size_t>(k) * a_size;
      if (m == nullptr) {
        std::copy_n(r_row, a_size, out);
        continue;
      }
      // y = (P_bᵀ P_b)⁻¹ r_row by the two triangular solves, then out = P_b y.
      for (int x = 0; x < t_size; ++x) {
        double v = r_row[x];
        for (int y = 0; y < x; ++y) v -= gram[x * t_size + y] * r_row[y];
        r_row[x] = v / gram[x * t_size + x];
      }
      for (int x = t_size - 1; x >= 0; --x) {
        double v = r_row[x];
        for (int y = x + 1; y < t_size; ++y) v -= gram[y * t_size + x] * r_row[y];
        r_row[x] = v / gram[x * t_size + x];
      }
      const double* pb = plus[b];
      for (int a = 0; a < a_size; ++a) {
        double v = 0.0;
        for (int x = 0; x < t_size; ++x) v += pb[a * t_size + x] * r_row[x];
        out[a] = v;
      }
    }
  }
  return true;
}

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_BATCHED_H_
