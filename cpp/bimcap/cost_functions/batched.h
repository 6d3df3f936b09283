// Several observations of one term that share their parameter blocks (a frame's floor points,
// the matches of one frame pair ...) in one residual block, with the term's robust loss applied
// to each observation.
#ifndef BIMCAP_COST_FUNCTIONS_BATCHED_H_
#define BIMCAP_COST_FUNCTIONS_BATCHED_H_

#include <ceres/cost_function.h>
#include <ceres/loss_function.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <utility>
#include <vector>

namespace bimcap {

// The observations i = 1..n of a term whose cost functions take the same parameter blocks, each
// with raw residual r_i (k values, the term's whitening and weight inside) and Jacobian J_i,
// in one residual block of n·k + 1 values. Ceres applies a loss to the squared norm of a whole
// block, so the block carries no Ceres loss: the term's loss ρ acts on each observation here, as
// Ceres would on a block of its own (its Corrector, Triggs et al.'s correction), and one last
// residual carries the rest of the robust cost:
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
// The per-observation cost functions are kept (owned) and evaluated one after the other into
// their rows of the block's residuals and Jacobians (row-major, rows × block size).
class BatchedCostFunction final : public ceres::CostFunction {
 public:
  // `loss` (null: plain squares) must outlive the cost function; `residuals_per_sample` = k.
  BatchedCostFunction(const ceres::LossFunction* loss, int residuals_per_sample)
      : loss_(loss), k_(residuals_per_sample) {}

  // Appends an observation (before the block goes into a problem); `index` is its position in
  // its term (for messages). All observations take the same parameter block sizes.
  void Add(std::unique_ptr<ceres::CostFunction> sample, int64_t index) {
    if (samples_.empty()) {
      const std::vector<int32_t>& sizes = sample->parameter_block_sizes();
      if (sizes.size() > kMaxBlocks || sample->num_residuals() != k_)
        throw std::logic_error("BatchedCostFunction: an observation of unexpected size");
      *mutable_parameter_block_sizes() = sizes;
    }
    samples_.push_back(std::move(sample));
    indices_.push_back(index);
    set_num_residuals(k_ * static_cast<int>(samples_.size()) + (loss_ != nullptr ? 1 : 0));
  }

  int num_samples() const { return static_cast<int>(samples_.size()); }
  int residuals_per_sample() const { return k_; }
  const ceres::CostFunction& sample(int i) const { return *samples_[i]; }
  int64_t sample_index(int i) const { return indices_[i]; }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const std::vector<int32_t>& sizes = parameter_block_sizes();
    const size_t num_blocks = sizes.size();
    const size_t n = samples_.size();
    double* sample_jacobians[kMaxBlocks];
    double rest = 0.0;  // Σ_i ρ_i − ‖r̃_i‖²
    for (size_t i = 0; i < n; ++i) {
      double* r = residuals + k_ * i;
      for (size_t b = 0; b < num_blocks; ++b) {
        sample_jacobians[b] = (jacobians != nullptr && jacobians[b] != nullptr)
                                  ? jacobians[b] + static_cast<size_t>(k_) * i * sizes[b]
                                  : nullptr;
      }
      if (!samples_[i]->Evaluate(parameters, r, jacobians != nullptr ? sample_jacobians : nullptr))
        return false;
      if (loss_ == nullptr) continue;
      double s = 0.0;
      for (int row = 0; row < k_; ++row) s += r[row] * r[row];
      double rho[3];
      loss_->Evaluate(s, rho);
      // Ceres' Corrector (internal/ceres/corrector.cc), observation by observation.
      const double sqrt_rho1 = std::sqrt(rho[1]);
      double residual_scaling = sqrt_rho1, alpha_sq_norm = 0.0;
      if (s > 0.0 && rho[2] > 0.0) {
        const double alpha = 1.0 - std::sqrt(1.0 + 2.0 * s * rho[2] / rho[1]);
        residual_scaling = sqrt_rho1 / (1.0 - alpha);
        alpha_sq_norm = alpha / s;
      }
      if (jacobians != nullptr) {
        for (size_t b = 0; b < num_blocks; ++b) {
          double* j = sample_jacobians[b];
          if (j == nullptr) continue;
          const int cols = sizes[b];
          for (int c = 0; c < cols; ++c) {
            double rt_j = 0.0;
            if (alpha_sq_norm != 0.0) {
              for (int row = 0; row < k_; ++row) rt_j += r[row] * j[row * cols + c];
            }
            for (int row = 0; row < k_; ++row) {
              j[row * cols + c] = sqrt_rho1 * (j[row * cols + c] - alpha_sq_norm * r[row] * rt_j);
            }
          }
        }
      }
      for (int row = 0; row < k_; ++row) r[row] *= residual_scaling;
      rest += rho[0] - residual_scaling * residual_scaling * s;
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

 private:
  const ceres::LossFunction* loss_;
  const int k_;
  std::vector<std::unique_ptr<ceres::CostFunction>> samples_;
  std::vector<int64_t> indices_;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_BATCHED_H_
