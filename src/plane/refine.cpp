// Robust point-to-plane refinement with Ceres. The only translation unit that includes Ceres.

#include <ceres/loss_function.h>
#include <ceres/problem.h>
#include <ceres/sized_cost_function.h>
#include <ceres/solver.h>
#include <ceres/sphere_manifold.h>

#include <cmath>
#include <deque>

#include "plane_internal.hpp"
#include "planesdf/plane.hpp"

namespace planesdf {
namespace {

// Residual n·p + d for one (centred) point; analytic Jacobians (p for n, 1 for d).
class PointToPlaneCost final : public ceres::SizedCostFunction<1, 3, 1> {
 public:
  explicit PointToPlaneCost(const Eigen::Vector3d& p) : p_(p) {}

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const double* n = parameters[0];
    residuals[0] = n[0] * p_.x() + n[1] * p_.y() + n[2] * p_.z() + parameters[1][0];
    if (jacobians != nullptr) {
      if (jacobians[0] != nullptr) {
        jacobians[0][0] = p_.x();
        jacobians[0][1] = p_.y();
        jacobians[0][2] = p_.z();
      }
      if (jacobians[1] != nullptr) jacobians[1][0] = 1.0;
    }
    return true;
  }

 private:
  Eigen::Vector3d p_;
};

ceres::Solver::Options solverOptions() {
  ceres::Solver::Options o;
  o.linear_solver_type = ceres::DENSE_QR;
  o.max_num_iterations = 50;
  // Converged well below a micrometre / microradian; tighter only adds iterations.
  o.function_tolerance = 1e-10;
  o.gradient_tolerance = 1e-12;
  o.parameter_tolerance = 1e-9;
  o.num_threads = 1;
  o.logging_type = ceres::SILENT;
  o.minimizer_progress_to_stdout = false;
  return o;
}

}  // namespace

bool refinePlane(const std::vector<Eigen::Vector3f>& inliers, Plane& plane, const Config& cfg) {
  validatePlaneConfig(cfg);
  const std::vector<std::uint32_t> pick = detail::evenSubsample(
      detail::validIndices(inliers), static_cast<std::size_t>(cfg.refine_max_points));
  if (pick.size() < 3) return false;
  // Centre the points for conditioning: residual n·(p - c) + d', with d' = d + n·c.
  const Eigen::Vector3d centre = detail::centroidOf(inliers, pick);
  const Eigen::Vector3d n0 = plane.normal.normalized();
  Eigen::Vector3d n = n0;
  double d = plane.offset + n.dot(centre);

  ceres::Problem::Options po;
  po.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  po.disable_all_safety_checks = true;  // thousands of identical, well-formed blocks
  ceres::Problem problem(po);
  ceres::CauchyLoss loss(cfg.refine_loss_scale);
  ceres::SphereManifold<3> sphere;
  std::deque<PointToPlaneCost> costs;
  for (std::uint32_t i : pick) {
    costs.emplace_back(inliers[i].cast<double>() - centre);
    problem.AddResidualBlock(&costs.back(), &loss, n.data(), &d);
  }
  problem.SetManifold(n.data(), &sphere);

  ceres::Solver::Summary summary;
  ceres::Solve(solverOptions(), &problem, &summary);
  if (!summary.IsSolutionUsable() || !n.allFinite() || !std::isfinite(d)) return false;
  n.normalize();
  double offset = d - n.dot(centre);
  if (n.dot(n0) < 0.0) {  // keep the free side
    n = -n;
    offset = -offset;
  }
  updatePlaneGeometry(plane, n, offset);
  return true;
}

}  // namespace planesdf
