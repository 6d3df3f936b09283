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
//
// Compressed form. Everything Ceres' trust-region step uses of a block is its cost, J̃ᵀJ̃,
// J̃ᵀr̃ and the column norms of J̃ (diag J̃ᵀJ̃); its linear solver forms J̃ᵀJ̃ row by row. Once
// the n·k rows outnumber the C ambient parameters of the block (C = Σ block sizes: 7 for one
// pose, 14 for two), the block is C + 1 rows instead, built from the same r̃_i, J̃_i:
//
//   H = Σ_i J̃_iᵀ J̃_i (C × C),   g = Σ_i J̃_iᵀ r̃_i,   c = Σ_i ρ_i  (Σ_i s_i without a loss)
//   H ≈ S Pᵀ L Lᵀ P S   (S = diag √H_aa; Cholesky of the equilibrated H with diagonal pivoting,
//                        rank m: pivots ≤ 1e-12, the directions H does not see, are dropped)
//   R = Lᵀ P S   (m × C, rows m..C−1 zero),   z = L⁻¹ P S⁻¹ g   (so Rᵀ z = g)
//   t = √(c − ‖z‖²)                                        (the last row; its Jacobian row is 0)
//
// So Rᵀ R = H, Rᵀ z = g and ½(‖z‖² + t²) = ½ c: the same cost, gradient, Gauss-Newton matrix
// and column norms (hence the same Levenberg-Marquardt diagonal and Jacobi scaling), to
// rounding, in C + 1 rows instead of n·k + 1. A residual-only evaluation (Ceres' candidate
// points: it reads the cost only) writes [√c, 0, ..., 0]. Columns of constant parameter blocks
// (a null jacobians[b]) are left out of H and g.
class BatchedCostFunction final : public ceres::CostFunction {
 public:
  // `loss` (null: plain squares) must outlive the cost function; `residuals_per_sample` = k.
  // `compress`: the compressed form above once n·k > C (false: always n·k + 1 rows).
  BatchedCostFunction(const ceres::LossFunction* loss, int residuals_per_sample,
                      bool compress = true)
      : loss_(loss), k_(residuals_per_sample), compress_(compress) {}

  // Appends an observation (before the block goes into a problem); `index` is its position in
  // its term (for messages). All observations take the same parameter block sizes.
  void Add(std::unique_ptr<ceres::CostFunction> sample, int64_t index) {
    if (samples_.empty()) {
      const std::vector<int32_t>& sizes = sample->parameter_block_sizes();
      if (sizes.size() > kMaxBlocks || sample->num_residuals() != k_ || k_ > kMaxK)
        throw std::logic_error("BatchedCostFunction: an observation of unexpected size");
      int cols = 0;
      for (const int32_t size : sizes) cols += size;
      if (cols > kMaxCols)
        throw std::logic_error("BatchedCostFunction: an observation of unexpected size");
      cols_ = cols;
      *mutable_parameter_block_sizes() = sizes;
    }
    samples_.push_back(std::move(sample));
    indices_.push_back(index);
    const int rows = k_ * static_cast<int>(samples_.size());
    compressed_ = compress_ && rows > cols_;
    set_num_residuals(compressed_ ? cols_ + 1 : rows + (loss_ != nullptr ? 1 : 0));
  }

  bool compressed() const { return compressed_; }

  int num_samples() const { return static_cast<int>(samples_.size()); }
  int residuals_per_sample() const { return k_; }
  const ceres::CostFunction& sample(int i) const { return *samples_[i]; }
  int64_t sample_index(int i) const { return indices_[i]; }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    if (compressed_) return EvaluateCompressed(parameters, residuals, jacobians);
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
  static constexpr int kMaxK = 4;          // residuals per observation
  static constexpr int kMaxCols = 32;      // Σ parameter block sizes

 private:
  // Ceres' Corrector for one observation's k residuals `r` and its k × cols row-major Jacobian
  // `j` (null: residuals only), in place; returns ρ(s) (s without a loss).
  double Correct(double* r, double* j, int cols) const {
    double s = 0.0;
    for (int row = 0; row < k_; ++row) s += r[row] * r[row];
    if (loss_ == nullptr) return s;
    double rho[3];
    loss_->Evaluate(s, rho);
    const double sqrt_rho1 = std::sqrt(rho[1]);
    double residual_scaling = sqrt_rho1, alpha_sq_norm = 0.0;
    if (s > 0.0 && rho[2] > 0.0) {
      const double alpha = 1.0 - std::sqrt(1.0 + 2.0 * s * rho[2] / rho[1]);
      residual_scaling = sqrt_rho1 / (1.0 - alpha);
      alpha_sq_norm = alpha / s;
    }
    if (j != nullptr) {
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
    for (int row = 0; row < k_; ++row) r[row] *= residual_scaling;
    return rho[0];
  }

  // H += Σ_rows jᵀ j (lower triangle of the cols × cols row-major h), g += Σ_rows jᵀ r over the
  // k × cols row-major j; K, C > 0 fix k and cols at compile time.
  template <int K, int C>
  static void Accumulate(const double* j, const double* r, double* h, double* g, int k = K,
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

  // The compressed form (see the class comment).
  bool EvaluateCompressed(double const* const* parameters, double* residuals,
                          double** jacobians) const {
    const std::vector<int32_t>& sizes = parameter_block_sizes();
    const size_t num_blocks = sizes.size();
    const int rows = cols_ + 1;
    // The blocks whose Jacobian is asked for, and their first column among those.
    int first[kMaxBlocks];
    int cols = 0;
    for (size_t b = 0; b < num_blocks; ++b) {
      const bool wanted = jacobians != nullptr && jacobians[b] != nullptr;
      first[b] = wanted ? cols : -1;
      if (wanted) cols += sizes[b];
    }
    double r[kMaxK];
    double block_j[kMaxK * kMaxCols];  // observation i's Jacobian, block by block (row-major)
    double j[kMaxK * kMaxCols];        // the same, k × cols row-major over the wanted columns
    double* sample_jacobians[kMaxBlocks];
    for (size_t b = 0, offset = 0; b < num_blocks; offset += k_ * sizes[b], ++b) {
      sample_jacobians[b] = first[b] >= 0 ? block_j + offset : nullptr;
    }
    double h[kMaxCols * kMaxCols];  // cols × cols row-major, lower triangle used
    double g[kMaxCols];
    std::fill_n(h, cols * cols, 0.0);
    std::fill_n(g, cols, 0.0);
    double total = 0.0;
    for (size_t i = 0; i < samples_.size(); ++i) {
      if (!samples_[i]->Evaluate(parameters, r, cols > 0 ? sample_jacobians : nullptr))
        return false;
      if (cols == 0) {
        total += Correct(r, nullptr, 0);
        continue;
      }
      for (size_t b = 0; b < num_blocks; ++b) {
        if (first[b] < 0) continue;
        for (int row = 0; row < k_; ++row) {
          std::copy_n(sample_jacobians[b] + row * sizes[b], sizes[b], j + row * cols + first[b]);
        }
      }
      total += Correct(r, j, cols);
      // The usual sizes with compile-time bounds (unrolled), else the same loops at run time.
      if (k_ == 1 && cols == 7) {
        Accumulate<1, 7>(j, r, h, g);
      } else if (k_ == 1 && cols == 14) {
        Accumulate<1, 14>(j, r, h, g);
      } else if (k_ == 2 && cols == 14) {
        Accumulate<2, 14>(j, r, h, g);
      } else if (k_ == 3 && cols == 14) {
        Accumulate<3, 14>(j, r, h, g);
      } else {
        Accumulate<0, 0>(j, r, h, g, k_, cols);
      }
    }
    std::fill_n(residuals, rows, 0.0);
    if (cols == 0) {
      residuals[rows - 1] = std::sqrt(std::max(total, 0.0));
      return true;
    }
    // Equilibrated: H' = S⁻¹ H S⁻¹, g' = S⁻¹ g with S = diag √H_aa (an empty column stays 0), so
    // that the factorisation's rounding is relative to each column's own scale, as in JᵀJ.
    double scale[kMaxCols];
    for (int a = 0; a < cols; ++a) scale[a] = std::sqrt(h[a * cols + a]);
    for (int a = 0; a < cols; ++a) {
      const double inv_a = scale[a] > 0.0 ? 1.0 / scale[a] : 0.0;
      g[a] *= inv_a;
      for (int c = 0; c <= a; ++c) {
        h[a * cols + c] *= inv_a * (scale[c] > 0.0 ? 1.0 / scale[c] : 0.0);
      }
    }
    // Cholesky with diagonal pivoting of H', in place (lower triangle): P H' Pᵀ = L Lᵀ.
    int perm[kMaxCols];
    for (int a = 0; a < cols; ++a) perm[a] = a;
    const double tol = 1e-12;
    auto at = [&](int a, int c) -> double& { return a >= c ? h[a * cols + c] : h[c * cols + a]; };
    int rank = 0;
    for (; rank < cols; ++rank) {
      const int k = rank;
      int p = k;
      for (int a = k + 1; a < cols; ++a) {
        if (at(a, a) > at(p, p)) p = a;
      }
      if (!(at(p, p) > tol)) break;
      if (p != k) {
        for (int c = 0; c < cols; ++c) {
          if (c != k && c != p) std::swap(at(k, c), at(p, c));
        }
        std::swap(at(k, k), at(p, p));
        std::swap(perm[k], perm[p]);
      }
      const double lkk = std::sqrt(at(k, k));
      at(k, k) = lkk;
      for (int a = k + 1; a < cols; ++a) at(a, k) /= lkk;
      for (int a = k + 1; a < cols; ++a) {
        for (int c = k + 1; c <= a; ++c) at(a, c) -= at(a, k) * at(c, k);
      }
    }
    // z = L⁻¹ P g (forward substitution over the rank rows), R = Lᵀ P.
    double z[kMaxCols];
    double z_sq = 0.0;
    for (int k = 0; k < rank; ++k) {
      double v = g[perm[k]];
      for (int c = 0; c < k; ++c) v -= at(k, c) * z[c];
      z[k] = v / at(k, k);
      z_sq += z[k] * z[k];
    }
    for (int k = 0; k < rank; ++k) residuals[k] = z[k];
    residuals[rows - 1] = std::sqrt(std::max(total - z_sq, 0.0));
    for (size_t b = 0; b < num_blocks; ++b) {
      if (first[b] < 0) continue;
      double* jb = jacobians[b];
      std::fill_n(jb, static_cast<size_t>(rows) * sizes[b], 0.0);
      for (int k = 0; k < rank; ++k) {
        // Row k of R = Lᵀ P: R(k, perm[a]) = L(a, k) for a ≥ k.
        for (int a = k; a < cols; ++a) {
          const int col = perm[a] - first[b];
          if (col >= 0 && col < sizes[b]) jb[k * sizes[b] + col] = at(a, k) * scale[perm[a]];
        }
      }
    }
    return true;
  }

  const ceres::LossFunction* loss_;
  const int k_;
  const bool compress_;
  int cols_ = 0;             // Σ parameter block sizes (C)
  bool compressed_ = false;  // n·k > C and compress_
  std::vector<std::unique_ptr<ceres::CostFunction>> samples_;
  std::vector<int64_t> indices_;
};

}  // namespace bimcap

#endif  // BIMCAP_COST_FUNCTIONS_BATCHED_H_
