// 3D voxel validation (paper §III-D): Hessians of the TSDF by composed 3D Sobel filters on dense
// patches, key voxels (local extrema of det(Hessian)), eigenpair-histogram features, the
// similarity and the blob verdict. The choices are documented in include/planesdf/validation.hpp.

#include "planesdf/validation.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <map>
#include <string>
#include <unordered_set>
#include <vector>

#include "../numeric.hpp"
#include "../parallel.hpp"
#include "planesdf/error.hpp"

namespace planesdf {
namespace {

constexpr int kHessianMargin = 2;  // the composed kernels reach 2 voxels
constexpr int kFeatureMargin = 3;  // Hessians of the 3x3x3 neighbourhood need 7x7x7 voxels
constexpr int kNeighbours = 27;
constexpr double kVotes = 3.0 * kNeighbours;  // eigenpairs of a neighbourhood
using detail::kPi;

// The 1D factors of the composed 5x5x5 kernels G_j * G_i, as correlation weights at offsets
// -2..2. With d = [-1, 0, 1] / 2 (central difference) and s = [1, 2, 1] / 4 (smoothing):
// S2 = s * s, D1 = d * s, D2 = d * d. E.g. s_xx = D2(x) S2(y) S2(z), s_xy = D1(x) D1(y) S2(z).
constexpr double kS2[5] = {1.0 / 16, 4.0 / 16, 6.0 / 16, 4.0 / 16, 1.0 / 16};
constexpr double kD1[5] = {-1.0 / 8, -2.0 / 8, 0.0, 2.0 / 8, 1.0 / 8};
constexpr double kD2[5] = {1.0 / 4, 0.0, -2.0 / 4, 0.0, 1.0 / 4};

void checkConfig(const Config& cfg) {
  featureSize(cfg);  // validates the bin counts
  if (!(cfg.sdf_sigma_voxels > 0.0) || !std::isfinite(cfg.sdf_sigma_voxels))
    throw Error("", "validation: sdf_sigma_voxels must be positive and finite");
  if (!(cfg.alpha >= 0.0) || !std::isfinite(cfg.alpha))
    throw Error("", "validation: alpha must be >= 0 and finite");
}

// ---- dense patches of a volume with their Hessians -------------------------------------------

/// A dense box of voxels [origin, origin + dims) copied out of a volume, with the Hessian of every
/// voxel whose 5x5x5 neighbourhood lies in the box and is observed.
struct HessianPatch {
  Eigen::Vector3i origin = Eigen::Vector3i::Zero();
  Eigen::Vector3i dims = Eigen::Vector3i::Zero();
  std::vector<double> phi;                  // m; 0 where unobserved
  std::vector<std::uint8_t> observed;       // weight > 0 and >= w_min, finite sdf
  std::vector<std::uint8_t> has_hess;       // 5x5x5 neighbourhood observed
  std::vector<std::array<double, 6>> hess;  // xx, yy, zz, xy, xz, yz (m / voxel²)

  std::size_t size() const { return static_cast<std::size_t>(dims.x()) * dims.y() * dims.z(); }
  std::ptrdiff_t stride(int axis) const {
    return axis == 0 ? 1 : axis == 1 ? dims.x() : std::ptrdiff_t{dims.x()} * dims.y();
  }
  bool contains(const Eigen::Vector3i& g) const {
    const Eigen::Vector3i l = g - origin;
    return (l.array() >= 0).all() && (l.array() < dims.array()).all();
  }
  /// Linear index of global voxel g; requires contains(g).
  std::ptrdiff_t index(const Eigen::Vector3i& g) const {
    const Eigen::Vector3i l = g - origin;
    return l.x() + std::ptrdiff_t{dims.x()} * (l.y() + std::ptrdiff_t{dims.y()} * l.z());
  }
  Eigen::Matrix3d hessian(std::ptrdiff_t i) const {
    const std::array<double, 6>& h = hess[static_cast<std::size_t>(i)];
    Eigen::Matrix3d m;
    m << h[0], h[3], h[4], h[3], h[1], h[5], h[4], h[5], h[2];
    return m;
  }
};

/// Copies the voxels of [origin, origin + dims) out of `vol`, block by block.
void fillPatch(const TsdfVolume& vol, float w_min, HessianPatch* p) {
  const std::size_t n = p->size();
  p->phi.assign(n, 0.0);
  p->observed.assign(n, 0);
  const Eigen::Vector3i lo = p->origin, hi = p->origin + p->dims - Eigen::Vector3i::Ones();
  const Eigen::Vector3i blo = TsdfVolume::blockOfVoxel(lo), bhi = TsdfVolume::blockOfVoxel(hi);
  for (int bz = blo.z(); bz <= bhi.z(); ++bz)
    for (int by = blo.y(); by <= bhi.y(); ++by)
      for (int bx = blo.x(); bx <= bhi.x(); ++bx) {
        const TsdfBlock* block = vol.findBlock(Eigen::Vector3i(bx, by, bz));
        if (!block) continue;
        const Eigen::Vector3i base = block->index * kTsdfBlockSide;
        const Eigen::Vector3i a = lo.cwiseMax(base);
        const Eigen::Vector3i b = hi.cwiseMin(base + Eigen::Vector3i::Constant(kTsdfBlockSide - 1));
        for (int z = a.z(); z <= b.z(); ++z)
          for (int y = a.y(); y <= b.y(); ++y)
            for (int x = a.x(); x <= b.x(); ++x) {
              const Eigen::Vector3i g(x, y, z);
              const TsdfVoxel& v = block->voxels[TsdfVolume::linearIndexInBlock(g)];
              if (!(v.weight > 0.0f && v.weight >= w_min) || !std::isfinite(v.sdf)) continue;
              const std::size_t i = static_cast<std::size_t>(p->index(g));
              p->phi[i] = v.sdf;
              p->observed[i] = 1;
            }
      }
}

/// out = the 5-tap correlation of `in` with `k` along `axis`, at the voxels at least 2 voxels
/// from the patch's faces along that axis (0 elsewhere).
void correlateAxis(const HessianPatch& p, const std::vector<double>& in, int axis,
                   const double (&k)[5], std::vector<double>* out) {
  out->assign(in.size(), 0.0);
  const std::ptrdiff_t s = p.stride(axis);
  const int n = p.dims[axis];
  std::ptrdiff_t i = 0;
  for (int z = 0; z < p.dims.z(); ++z)
    for (int y = 0; y < p.dims.y(); ++y)
      for (int x = 0; x < p.dims.x(); ++x, ++i) {
        const int c = axis == 0 ? x : axis == 1 ? y : z;
        if (c < kHessianMargin || c >= n - kHessianMargin) continue;
        const double* q = in.data() + i;
        (*out)[static_cast<std::size_t>(i)] =
            k[0] * q[-2 * s] + k[1] * q[-s] + k[2] * q[0] + k[3] * q[s] + k[4] * q[2 * s];
      }
}

/// out = 1 where the 5 voxels centred on a voxel along `axis` are all set in `in`.
void erodeAxis(const HessianPatch& p, const std::vector<std::uint8_t>& in, int axis,
               std::vector<std::uint8_t>* out) {
  out->assign(in.size(), 0);
  const std::ptrdiff_t s = p.stride(axis);
  const int n = p.dims[axis];
  std::ptrdiff_t i = 0;
  for (int z = 0; z < p.dims.z(); ++z)
    for (int y = 0; y < p.dims.y(); ++y)
      for (int x = 0; x < p.dims.x(); ++x, ++i) {
        const int c = axis == 0 ? x : axis == 1 ? y : z;
        if (c < kHessianMargin || c >= n - kHessianMargin) continue;
        const std::uint8_t* q = in.data() + i;
        (*out)[static_cast<std::size_t>(i)] = q[-2 * s] & q[-s] & q[0] & q[s] & q[2 * s];
      }
}

/// Fills has_hess and hess from phi / observed with separable passes (x, then y, then z).
void computeHessians(HessianPatch* p) {
  const std::size_t n = p->size();
  p->has_hess.assign(n, 0);
  p->hess.assign(n, {});
  if ((p->dims.array() < 2 * kHessianMargin + 1).any()) return;

  std::vector<std::uint8_t> m1, m2;
  erodeAxis(*p, p->observed, 0, &m1);
  erodeAxis(*p, m1, 1, &m2);
  erodeAxis(*p, m2, 2, &p->has_hess);

  // Along x: smooth, first and second derivative.
  std::vector<double> xs, xd, xdd;
  correlateAxis(*p, p->phi, 0, kS2, &xs);
  correlateAxis(*p, p->phi, 0, kD1, &xd);
  correlateAxis(*p, p->phi, 0, kD2, &xdd);
  // Along y, then z, one Hessian component at a time.
  std::vector<double> t, r;
  const auto store = [&](int component) {
    for (std::size_t i = 0; i < n; ++i)
      if (p->has_hess[i]) p->hess[i][static_cast<std::size_t>(component)] = r[i];
  };
  correlateAxis(*p, xdd, 1, kS2, &t);  // xx = D2 S2 S2
  correlateAxis(*p, t, 2, kS2, &r);
  store(0);
  correlateAxis(*p, xs, 1, kD2, &t);  // yy = S2 D2 S2
  correlateAxis(*p, t, 2, kS2, &r);
  store(1);
  correlateAxis(*p, xs, 1, kS2, &t);  // zz = S2 S2 D2
  correlateAxis(*p, t, 2, kD2, &r);
  store(2);
  correlateAxis(*p, xd, 1, kD1, &t);  // xy = D1 D1 S2
  correlateAxis(*p, t, 2, kS2, &r);
  store(3);
  correlateAxis(*p, xd, 1, kS2, &t);  // xz = D1 S2 D1
  correlateAxis(*p, t, 2, kD1, &r);
  store(4);
  correlateAxis(*p, xs, 1, kD1, &t);  // yz = S2 D1 D1
  correlateAxis(*p, t, 2, kD1, &r);
  store(5);
}

/// The patch [origin, origin + dims) of `vol` with its Hessians.
HessianPatch makePatch(const TsdfVolume& vol, const Eigen::Vector3i& origin,
                       const Eigen::Vector3i& dims, float w_min) {
  HessianPatch p;
  p.origin = origin;
  p.dims = dims;
  fillPatch(vol, w_min, &p);
  computeHessians(&p);
  return p;
}

/// The cube of side 2 * margin + 1 centred on v.
HessianPatch patchAround(const TsdfVolume& vol, const Eigen::Vector3i& v, int margin, float w_min) {
  return makePatch(vol, v - Eigen::Vector3i::Constant(margin),
                   Eigen::Vector3i::Constant(2 * margin + 1), w_min);
}

// ---- features -----------------------------------------------------------------------------

/// Offset of neighbour n (0..26) of the 3x3x3 neighbourhood, x fastest.
Eigen::Vector3i neighbourOffset(int n) {
  return Eigen::Vector3i(n % 3 - 1, (n / 3) % 3 - 1, n / 9 - 1);
}

/// The Hessians and SDF values of the 3x3x3 neighbourhood of a voxel.
struct Neighbourhood {
  std::array<Eigen::Matrix3d, kNeighbours> hess;
  std::array<double, kNeighbours> phi{};
};

/// Gathers the neighbourhood of v0 from `p`; false when a voxel of it has no Hessian.
bool gatherNeighbourhood(const HessianPatch& p, const Eigen::Vector3i& v0, Neighbourhood* out) {
  for (int n = 0; n < kNeighbours; ++n) {
    const Eigen::Vector3i g = v0 + neighbourOffset(n);
    if (!p.contains(g)) return false;
    const std::ptrdiff_t i = p.index(g);
    if (!p.has_hess[static_cast<std::size_t>(i)]) return false;
    out->hess[static_cast<std::size_t>(n)] = p.hessian(i);
    out->phi[static_cast<std::size_t>(n)] = p.phi[static_cast<std::size_t>(i)];
  }
  return true;
}

/// The fixed frame directions are binned in (see validation.hpp, "Directions").
struct HistogramFrame {
  Eigen::Vector3d x, y, z;
};

const HistogramFrame& histogramFrame() {
  static const HistogramFrame frame = [] {
    HistogramFrame f;
    f.y = Eigen::Vector3d(5.0, 2.0, 2.0).normalized();
    f.z = (Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitZ().dot(f.y) * f.y).normalized();
    f.x = f.y.cross(f.z);
    return f;
  }();
  return frame;
}

/// (θ, φ) in degrees of the axis ±e (unit) in the histogram frame.
Eigen::Vector2d sphericalDeg(const Eigen::Vector3d& e) {
  const HistogramFrame& f = histogramFrame();
  double a = e.dot(f.x), b = e.dot(f.y), c = e.dot(f.z);
  if (b < 0.0) {
    a = -a;
    b = -b;
    c = -c;
  }
  const double theta = std::atan2(std::abs(b), a);  // [0, π]
  const double phi = std::asin(std::clamp(c, -1.0, 1.0));
  return Eigen::Vector2d(theta * 180.0 / kPi, phi * 180.0 / kPi);
}

/// A vote's share in (at most) two neighbouring bins.
struct BinShare {
  int b0 = 0, b1 = 0;
  double w0 = 1.0, w1 = 0.0;
};

/// The bins value x falls in among n bins over [lo, hi]; values outside go to the end bins.
BinShare binShare(double x, double lo, double hi, int n, bool soft) {
  const double width = hi - lo;
  BinShare s;
  if (!(width > 0.0)) {  // degenerate range: at or below it -> first bin, above -> last
    s.b0 = s.b1 = x > hi ? n - 1 : 0;
    return s;
  }
  const double u = (x - lo) / width * n;  // in bin units, 0 at lo
  if (!soft) {
    s.b0 = s.b1 = static_cast<int>(std::clamp(std::floor(u), 0.0, n - 1.0));
    return s;
  }
  const double c = u - 0.5;  // in bin-centre units
  if (c <= 0.0 || n == 1) {
    s.b0 = s.b1 = 0;
  } else if (c >= n - 1.0) {
    s.b0 = s.b1 = n - 1;
  } else {
    s.b0 = static_cast<int>(std::floor(c));
    s.b1 = s.b0 + 1;
    s.w1 = c - s.b0;
    s.w0 = 1.0 - s.w1;
  }
  return s;
}

/// One eigenpair: normalised eigenvalue and direction angles (degrees).
struct Eigenpair {
  double lambda = 0.0;
  double theta = 0.0;
  double phi = 0.0;
};
using Eigenpairs = std::array<std::array<Eigenpair, 3>, kNeighbours>;

/// Eigenpairs of the neighbourhood's Hessians, eigenvalues ascending and divided by the largest
/// |λ| of the neighbourhood, directions rotated by R_ref.
Eigenpairs eigenpairs(const Neighbourhood& nb, const Eigen::Matrix3d& R_ref) {
  Eigenpairs pairs;
  std::array<Eigen::Vector3d, kNeighbours> values;
  double max_abs = 0.0;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
  for (std::size_t n = 0; n < kNeighbours; ++n) {
    es.computeDirect(nb.hess[n]);  // eigenvalues ascending
    values[n] = es.eigenvalues();
    max_abs = std::max(max_abs, values[n].cwiseAbs().maxCoeff());
    for (int i = 0; i < 3; ++i) {
      const Eigen::Vector2d tp = sphericalDeg(R_ref * es.eigenvectors().col(i));
      pairs[n][static_cast<std::size_t>(i)].theta = tp.x();
      pairs[n][static_cast<std::size_t>(i)].phi = tp.y();
    }
  }
  const double scale = max_abs > 0.0 ? 1.0 / max_abs : 0.0;
  for (std::size_t n = 0; n < kNeighbours; ++n)
    for (std::size_t i = 0; i < 3; ++i) pairs[n][i].lambda = values[n][static_cast<int>(i)] * scale;
  return pairs;
}

LambdaRanges lambdaRanges(const Eigenpairs& pairs) {
  LambdaRanges r;
  for (std::size_t i = 0; i < 3; ++i) {
    r.min[i] = r.max[i] = pairs[0][i].lambda;
    for (const auto& p : pairs) {
      r.min[i] = std::min(r.min[i], p[i].lambda);
      r.max[i] = std::max(r.max[i], p[i].lambda);
    }
  }
  return r;
}

/// Σ w Φ / Σ w over the neighbourhood (Gaussian weights of σ voxels), divided by `truncation`.
double weightedSdf(const Neighbourhood& nb, double sigma_voxels, double truncation) {
  double sw = 0.0, swp = 0.0;
  for (int n = 0; n < kNeighbours; ++n) {
    const double d2 = neighbourOffset(n).squaredNorm();
    const double w = std::exp(-d2 / (2.0 * sigma_voxels * sigma_voxels));
    sw += w;
    swp += w * nb.phi[static_cast<std::size_t>(n)];
  }
  return swp / sw / truncation;
}

/// The feature [h_1 | h_2 | h_3 | s] of a neighbourhood, binned with `ranges`.
Eigen::VectorXd buildFeature(const Eigenpairs& pairs, const LambdaRanges& ranges, double s,
                             const Config& cfg, bool soft, bool magnitude_weighted) {
  const int nt = cfg.bins_theta, np = cfg.bins_phi, nl = cfg.bins_lambda;
  const int sub = nt * np * nl;
  Eigen::VectorXd f = Eigen::VectorXd::Zero(3 * sub + 1);
  for (const auto& p : pairs)
    for (std::size_t i = 0; i < 3; ++i) {
      const double vote = (magnitude_weighted ? std::abs(p[i].lambda) : 1.0) / kVotes;
      const BinShare bt = binShare(p[i].theta, 0.0, 180.0, nt, soft);
      const BinShare bp = binShare(p[i].phi, -90.0, 90.0, np, soft);
      const BinShare bl = binShare(p[i].lambda, ranges.min[i], ranges.max[i], nl, soft);
      const int off = static_cast<int>(i) * sub;
      for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b)
          for (int c = 0; c < 2; ++c) {
            const double w = (a ? bt.w1 : bt.w0) * (b ? bp.w1 : bp.w0) * (c ? bl.w1 : bl.w0);
            if (w == 0.0) continue;
            const int t = a ? bt.b1 : bt.b0, q = b ? bp.b1 : bp.b0, l = c ? bl.b1 : bl.b0;
            f[off + (t * np + q) * nl + l] += vote * w;
          }
    }
  f[3 * sub] = s;
  return f;
}

/// The feature of v0 from patch `p` (which must hold its 7x7x7 neighbourhood's Hessians).
/// `ranges` null: the source feature, ranges from the neighbourhood itself.
std::optional<VoxelFeature> featureInPatch(const HessianPatch& p, const Eigen::Vector3i& v0,
                                           const LambdaRanges* ranges, double truncation,
                                           const Eigen::Matrix3d& R_ref, const Config& cfg,
                                           const ValidationParams& params) {
  Neighbourhood nb;
  if (!gatherNeighbourhood(p, v0, &nb)) return std::nullopt;
  const Eigenpairs pairs = eigenpairs(nb, R_ref);
  VoxelFeature f;
  f.ranges = ranges ? *ranges : lambdaRanges(pairs);
  f.values = buildFeature(pairs, f.ranges, weightedSdf(nb, cfg.sdf_sigma_voxels, truncation), cfg,
                          params.soft_binning, params.magnitude_weighted_votes);
  return f;
}

// ---- key voxels ---------------------------------------------------------------------------

/// Strict local extremum of det over the 26 neighbours (ties broken by the smaller index).
bool isLocalExtremum(const std::vector<double>& det, std::ptrdiff_t i, const HessianPatch& p) {
  const double d = det[static_cast<std::size_t>(i)];
  bool is_max = true, is_min = true;
  for (int n = 0; n < kNeighbours && (is_max || is_min); ++n) {
    if (n == 13) continue;  // the centre
    const Eigen::Vector3i o = neighbourOffset(n);
    const std::ptrdiff_t j = i + o.x() * p.stride(0) + o.y() * p.stride(1) + o.z() * p.stride(2);
    const double e = det[static_cast<std::size_t>(j)];
    if (std::isnan(e)) return false;  // incomplete neighbourhood
    const bool first = i < j;
    if (!(d > e || (d == e && first))) is_max = false;
    if (!(d < e || (d == e && first))) is_min = false;
  }
  return is_max || is_min;
}

/// Bounding box of `voxels` (not empty) grown by kFeatureMargin.
std::pair<Eigen::Vector3i, Eigen::Vector3i> boundsWithMargin(
    const std::vector<Eigen::Vector3i>& voxels) {
  Eigen::Vector3i lo = voxels.front(), hi = voxels.front();
  for (const Eigen::Vector3i& v : voxels) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  return {lo.array() - kFeatureMargin, hi.array() + kFeatureMargin};
}

/// Columns per side of the tiles key voxels are searched in.
constexpr int kKeyTile = 32;

/// Key voxels of `blob` (see keyVoxels). A voxel's det and its neighbours' depend only on the
/// voxels within kFeatureMargin of it, so the blob is searched tile by tile (kKeyTile^2 columns),
/// each with a dense patch of its voxels' box plus that margin: the result equals one patch over
/// the blob's whole box (what the method defines), at a cost that follows the blob's voxels
/// rather than its bounding box (a thin blob along a wall spans metres).
std::vector<KeyVoxel> findKeyVoxels(const TsdfVolume& vol, const std::vector<Eigen::Vector3i>& blob,
                                    float w_min, const ValidationParams& params) {
  if (blob.empty()) return {};
  const std::pair<Eigen::Vector3i, Eigen::Vector3i> box = boundsWithMargin(blob);
  const Eigen::Vector3i lo = box.first, hi = box.second;  // named: the lambda below captures lo
  const Eigen::Vector3i dims = hi - lo + Eigen::Vector3i::Ones();
  const long long cells = static_cast<long long>(dims.x()) * dims.y() * dims.z();
  if (cells > params.max_box_voxels)
    throw Error("", "validation: the blob's bounding box (" + std::to_string(dims.x()) + " x " +
                        std::to_string(dims.y()) + " x " + std::to_string(dims.z()) +
                        " voxels) exceeds max_box_voxels (" +
                        std::to_string(params.max_box_voxels) + ")");
  // Linear index in the whole box (z, y, x order): the tie-break between equal |det|.
  const auto box_index = [&](const Eigen::Vector3i& v) {
    const Eigen::Vector3i l = v - lo;
    return l.x() +
           static_cast<long long>(dims.x()) * (l.y() + static_cast<long long>(dims.y()) * l.z());
  };
  // The blob's voxels by tile (tiles in index order, voxels in blob order).
  std::map<std::pair<int, int>, std::vector<Eigen::Vector3i>> tiles;
  for (const Eigen::Vector3i& v : blob)
    tiles[{(v.x() - lo.x()) / kKeyTile, (v.y() - lo.y()) / kKeyTile}].push_back(v);

  const double vs = vol.voxelSize();
  const double inv_vs3 = 1.0 / (vs * vs * vs);
  std::vector<KeyVoxel> keys;
  std::vector<double> det;
  std::vector<std::uint8_t> seen;
  for (const auto& tile : tiles) {
    const std::vector<Eigen::Vector3i>& voxels = tile.second;
    const auto [tlo, thi] = boundsWithMargin(voxels);
    const HessianPatch p = makePatch(vol, tlo, thi - tlo + Eigen::Vector3i::Ones(), w_min);
    // det in voxel units; NaN where there is no Hessian.
    det.assign(p.size(), std::nan(""));
    for (std::size_t i = 0; i < p.size(); ++i)
      if (p.has_hess[i]) det[i] = p.hessian(static_cast<std::ptrdiff_t>(i)).determinant() * inv_vs3;
    seen.assign(p.size(), 0);
    for (const Eigen::Vector3i& v : voxels) {
      const std::ptrdiff_t i = p.index(v);
      if (seen[static_cast<std::size_t>(i)]) continue;
      seen[static_cast<std::size_t>(i)] = 1;
      const double d = det[static_cast<std::size_t>(i)];
      if (!(std::abs(d) >= params.min_abs_det)) continue;  // also NaN
      if (isLocalExtremum(det, i, p)) keys.push_back({v, d});
    }
  }
  const auto stronger = [&](const KeyVoxel& a, const KeyVoxel& b) {
    if (std::abs(a.det) != std::abs(b.det)) return std::abs(a.det) > std::abs(b.det);
    return box_index(a.voxel) < box_index(b.voxel);
  };
  std::sort(keys.begin(), keys.end(), stronger);
  if (static_cast<int>(keys.size()) > std::max(0, params.max_key_voxels))
    keys.resize(static_cast<std::size_t>(std::max(0, params.max_key_voxels)));
  return keys;
}

}  // namespace

// ---- public API ---------------------------------------------------------------------------

int featureSize(const Config& cfg) {
  const auto ok = [](int n) { return n >= 1 && n <= 64; };
  if (!ok(cfg.bins_theta) || !ok(cfg.bins_phi) || !ok(cfg.bins_lambda))
    throw Error("", "validation: bins_theta, bins_phi and bins_lambda must be in [1, 64]");
  return 3 * cfg.bins_theta * cfg.bins_phi * cfg.bins_lambda + 1;
}

std::optional<Eigen::Matrix3d> hessianAt(const TsdfVolume& vol, const Eigen::Vector3i& v,
                                         float w_min) {
  const HessianPatch p = patchAround(vol, v, kHessianMargin, w_min);
  const std::ptrdiff_t i = p.index(v);
  if (!p.has_hess[static_cast<std::size_t>(i)]) return std::nullopt;
  return p.hessian(i);
}

std::vector<KeyVoxel> keyVoxels(const TsdfVolume& vol, const std::vector<Eigen::Vector3i>& blob,
                                const Config& cfg, const ValidationParams& params) {
  if (blob.empty()) return {};
  return findKeyVoxels(vol, blob, cfg.w_min, params);
}

std::optional<VoxelFeature> featureAt(const TsdfVolume& vol, const Eigen::Vector3i& v0,
                                      const Config& cfg, const ValidationParams& params) {
  checkConfig(cfg);
  const HessianPatch p = patchAround(vol, v0, kFeatureMargin, cfg.w_min);
  return featureInPatch(p, v0, nullptr, vol.truncation(), Eigen::Matrix3d::Identity(), cfg, params);
}

std::optional<VoxelFeature> featureAt(const TsdfVolume& vol, const Eigen::Vector3i& v0,
                                      const LambdaRanges& ranges, const Config& cfg,
                                      const Eigen::Matrix3d& R_ref_vol,
                                      const ValidationParams& params) {
  checkConfig(cfg);
  const HessianPatch p = patchAround(vol, v0, kFeatureMargin, cfg.w_min);
  return featureInPatch(p, v0, &ranges, vol.truncation(), R_ref_vol, cfg, params);
}

double similarity(const Eigen::VectorXd& f, const Eigen::VectorXd& g, double alpha) {
  if (f.size() != g.size())
    throw Error("", "validation: features of different sizes (" + std::to_string(f.size()) +
                        " and " + std::to_string(g.size()) + ")");
  return 1.0 / (1.0 + alpha * (f - g).norm());
}

std::vector<Eigen::Vector3i> blobVoxelsFromColumns(const TsdfVolume& vol,
                                                   const std::vector<Eigen::Vector2i>& columns,
                                                   int k_min, int k_max, float w_min) {
  std::vector<Eigen::Vector3i> out;
  std::unordered_set<std::uint64_t> seen;
  for (const Eigen::Vector2i& c : columns) {
    const std::uint64_t key =
        (static_cast<std::uint64_t>(static_cast<std::uint32_t>(c.x())) << 32) |
        static_cast<std::uint32_t>(c.y());
    if (!seen.insert(key).second) continue;
    for (int k = k_min; k <= k_max; ++k) {
      const Eigen::Vector3i g(c.x(), c.y(), k);
      const TsdfVoxel* v = vol.voxel(g);
      if (v && v->weight > 0.0f && v->weight >= w_min) out.push_back(g);
    }
  }
  return out;
}

const char* toString(BlobValidation::Verdict v) {
  switch (v) {
    case BlobValidation::Verdict::Changed:
      return "changed";
    case BlobValidation::Verdict::Unchanged:
      return "unchanged";
    case BlobValidation::Verdict::Unknown:
      break;
  }
  return "unknown";
}

ValidationParams validationParams(const Config& cfg) {
  ValidationParams p;
  p.min_abs_det = cfg.key_min_abs_det;
  p.max_key_voxels = cfg.key_max_voxels;
  p.min_scored = cfg.verdict_min_scored;
  p.min_scored_splatted = cfg.verdict_min_scored_splatted;
  return p;
}

BlobValidation validateBlob(const TsdfVolume& source, const TsdfVolume& target,
                            const Pose& T_target_source,
                            const std::vector<Eigen::Vector3i>& blob_voxels, const Config& cfg,
                            const ValidationParams& params) {
  checkConfig(cfg);
  if (std::abs(source.voxelSize() - target.voxelSize()) > 1e-9 * source.voxelSize())
    throw Error("", "validation: source and target voxel sizes differ (" +
                        std::to_string(source.voxelSize()) + " and " +
                        std::to_string(target.voxelSize()) + " m)");
  if (!T_target_source.matrix().allFinite())
    throw Error("", "validation: T_target_source is not finite");
  BlobValidation out;
  if (blob_voxels.empty()) return out;

  const std::vector<KeyVoxel> keys = findKeyVoxels(source, blob_voxels, cfg.w_min, params);
  out.key_voxels = static_cast<int>(keys.size());
  out.keys.resize(keys.size());
  const Eigen::Matrix3d R_source_target = T_target_source.linear().transpose();

  const int n = static_cast<int>(keys.size());
  const auto scoreKey = [&](int k) {
    KeyVoxelScore& score = out.keys[static_cast<std::size_t>(k)];
    const KeyVoxel& key = keys[static_cast<std::size_t>(k)];
    score.voxel = key.voxel;
    score.det = key.det;
    score.target_voxel = target.voxelIndexAt(T_target_source * source.voxelCenter(key.voxel));
    // The feature needs the voxels within kFeatureMargin of the key only.
    const HessianPatch sp = patchAround(source, key.voxel, kFeatureMargin, cfg.w_min);
    const std::optional<VoxelFeature> f = featureInPatch(
        sp, key.voxel, nullptr, source.truncation(), Eigen::Matrix3d::Identity(), cfg, params);
    if (!f) return;  // cannot happen for a key voxel; kept for safety
    const HessianPatch tp = patchAround(target, score.target_voxel, kFeatureMargin, cfg.w_min);
    const std::optional<VoxelFeature> g = featureInPatch(
        tp, score.target_voxel, &f->ranges, target.truncation(), R_source_target, cfg, params);
    if (!g) return;
    score.scored = true;
    score.similarity = similarity(f->values, g->values, cfg.alpha);
  };
  detail::parallelChunks(n, detail::resolveThreads(cfg.threads), 4,
                         [&](int, long long begin, long long end) {
                           for (long long k = begin; k < end; ++k) scoreKey(static_cast<int>(k));
                         });

  double sum = 0.0;
  for (const KeyVoxelScore& s : out.keys)
    if (s.scored) {
      out.similarities.push_back(s.similarity);
      sum += s.similarity;
    }
  out.scored = static_cast<int>(out.similarities.size());
  if (out.scored == 0) return out;  // Unknown
  out.mean_similarity = sum / out.scored;
  if (out.scored < params.min_scored) return out;  // Unknown: too little 3D evidence
  out.verdict = out.mean_similarity < cfg.delta_blob ? BlobValidation::Verdict::Changed
                                                     : BlobValidation::Verdict::Unchanged;
  return out;
}

}  // namespace planesdf
