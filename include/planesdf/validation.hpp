#pragma once
/// \file validation.hpp
/// 3D voxel validation of a changed-object candidate (paper §III-D; design.md, "Pipeline"): key
/// voxels of a source voxel blob are local extrema of the determinant of the TSDF Hessian; each
/// gets a 451-dim shape feature (eigenpair histograms of the Hessians of its 3x3x3 neighbourhood
/// plus a Gaussian-weighted SDF), compared with the feature of the corresponding target location;
/// the blob is changed when the mean similarity < δ_blob.
///
/// Choices made where the paper is vague (all documented again at the functions below):
///  * Units. Voxel indices are global TSDF voxel indices (see tsdf.hpp). The 3D Sobel filter is
///    G_x(dx, dy, dz) = d(dx) s(dy) s(dz) / 32 with d = [-1, 0, 1], s = [1, 2, 1], so a first
///    derivative is in sdf-units (metres) per voxel; the Hessian s_ij = G_j * (G_i * Φ) is in
///    metres per voxel², i.e. the 5x5x5 composed kernels give exactly diag(2a, 2b, 2c) for
///    Φ = a i² + b j² + c k² (i, j, k voxel indices). Determinants (key voxel threshold,
///    KeyVoxel::det) are those of the Hessian in *voxel units*, H / voxel_size (the SDF measured in
///    voxels).
///  * Observed voxel: allocated with weight > 0 and >= cfg.w_min. A voxel has a Hessian only when
///    its whole 5x5x5 neighbourhood is observed; a voxel has a feature only when all 27 voxels of
///    its 3x3x3 neighbourhood have a Hessian (its 7x7x7 neighbourhood is observed).
///  * Key voxels: blob voxels with a complete 3x3x3 neighbourhood of Hessians whose det is a strict
///    maximum or strict minimum over the 26 neighbours (ties are broken by voxel index, so a
///    plateau yields at most one key voxel), with |det| >= ValidationParams::min_abs_det (rejects
///    noise of flat regions: an exact SDF has a zero eigenvalue along its gradient, so det is small
///    except at surface ridges, truncation kinks and between surfaces), at most
///    ValidationParams::max_key_voxels of them (largest |det| first).
///  * Eigenpairs: eigenvalues sorted ascending (sub-histogram i holds the i-th smallest) and
///    divided by the largest |λ| over all 81 eigenvalues of the neighbourhood (the
///    neighbourhood's own, for source and target alike; all zero stays zero), so λ ∈ [-1, 1] and
///    the feature is invariant to the SDF's scale. Target eigenvectors are rotated into the source
///    frame (by the rotation of T_target_source⁻¹) before binning.
///  * Directions (e ≡ -e): e is expressed in a fixed *histogram frame* (x_h, y_h, z_h) with
///    y_h = (5, 2, 2)/√33 in plane-local coordinates, z_h = the plane normal made orthogonal to
///    y_h, x_h = y_h × z_h; e is flipped so that e·y_h >= 0, then
///    θ = atan2(e·y_h, e·x_h) ∈ [0°, 180°] and φ = asin(e·z_h) ∈ [-90°, 90°] (the paper's
///    ranges). The flip (and the poles) make the parametrisation discontinuous on the great
///    circle e·y_h = 0; y_h is chosen so that the plane normal, the in-plane axes and their
///    diagonals — the most frequent directions of a PlaneSDF — are all >= 20° away from that
///    circle, so noise does not flip them between θ ≈ 0° and 180°.
///  * Histograms: N_θ x N_φ x N_λ bins per sub-histogram over θ ∈ [0°, 180°], φ ∈ [-90°, 90°],
///    λ ∈ [min, max] of the source neighbourhood's i-th eigenvalues (the target uses the source's λ
///    ranges; target values outside them count in the end bins). Index of bin (t, p, l) of
///    sub-histogram i: i N_θ N_φ N_λ + (t N_φ + p) N_λ + l. Two robustness choices of ours, both
///    on by default (ValidationParams; off = the paper's plain histogram):
///    - linear (soft) binning: a vote is shared between the two nearest bin centres along each of
///      θ, φ and λ (up to 8 bins, shares summing to 1), so a small perturbation of an eigenpair
///      moves a little mass instead of a whole vote;
///    - magnitude weighting: an eigenpair votes with weight |λ| (normalised, so <= 1), as image
///      descriptors weight orientations by gradient magnitude; the directions of near-zero
///      eigenvalues (along the SDF gradient, along edges, in degenerate eigenspaces) are defined by
///      noise only and get almost no weight.
///    Normalisation: votes are divided by the number of eigenpairs 3|N| = 81, so the histogram
///    part sums to 1 for unweighted votes and to Σ|λ| / 81 <= 1 with magnitude weighting. With the
///    paper's α = 2 and δ_blob = 0.9 this scale gives mean similarities of about 0.94 for the same
///    object under 1 mm of independent SDF noise and <= 0.75 for replaced objects (see the tests);
///    the same box fused from two different camera rings scores about 0.85 (projective fusion
///    differs systematically between viewpoints), so real data may need α / δ_blob tuned, as the
///    paper did for its real dataset.
///  * Weighted SDF s (last element): Σ w Φ / Σ w over the 27 voxels, w = exp(-|v - v0|² / (2σ²)),
///    σ = cfg.sdf_sigma_voxels voxels, divided by the volume's truncation so s ∈ [-1, 1] (a raw
///    value in metres would be negligible next to the histogram, one in voxels would dominate it).
///  * Correspondence: v0' = the target voxel containing T_target_source * centre(v0) (nearest
///    voxel); N' is the target's 3x3x3 neighbourhood of v0'. Both volumes must have the same voxel
///    size.
///  * Scores: a key voxel whose target neighbourhood has no feature (unobserved) is skipped and
///    not scored. The blob verdict uses the exact mean of the scores (the paper's histogram mean
///    Σ m_i n_i / N without the binning error); fewer scored key voxels than
///    ValidationParams::min_scored (3) give Verdict::Unknown.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <optional>
#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/tsdf.hpp"
#include "planesdf/types.hpp"

namespace planesdf {

/// How keyVoxels() and validateBlob() work: the thresholds are Config's (validationParams), the
/// rest are method switches and a size limit (ours, not the paper's).
struct ValidationParams {
  double min_abs_det = Config{}.key_min_abs_det;  ///< Config::key_min_abs_det
  int max_key_voxels = Config{}.key_max_voxels;   ///< Config::key_max_voxels
  /// Linear (soft) binning of the eigenpair votes; false = hard binning.
  bool soft_binning = true;
  /// Eigenpairs vote with weight |λ| (normalised); false = every eigenpair votes 1.
  bool magnitude_weighted_votes = true;
  /// Largest bounding box (in voxels, margin included) of a blob validateBlob()/keyVoxels() accept.
  long long max_box_voxels = 1LL << 24;
  /// A verdict (Changed or Unchanged) needs at least this many scored key voxels; with fewer the
  /// blob is Unknown (its mean similarity is still reported). Config::verdict_min_scored.
  int min_scored = Config{}.verdict_min_scored;
  /// min_scored where either map was splatted from a cloud without a pixel grid
  /// (Config::verdict_min_scored_splatted; the change detection switches to it).
  int min_scored_splatted = Config{}.verdict_min_scored_splatted;
};

/// The ValidationParams of `cfg` (key_min_abs_det, key_max_voxels, verdict_min_scored*).
ValidationParams validationParams(const Config& cfg);

/// Length of a feature: 3 N_θ N_φ N_λ + 1 (451 with the defaults). Throws planesdf::Error when a
/// bin count of `cfg` is < 1 or > 64.
int featureSize(const Config& cfg);

/// The Hessian of the SDF at global voxel `v` of `vol`: s_ij = G_j * (G_i * Φ) with the 3D Sobel
/// filter normalised to metres per voxel (see the file comment), so in metres per voxel². Empty
/// when a voxel of the 5x5x5 neighbourhood of `v` is unobserved (unallocated, weight 0 or
/// weight < w_min).
std::optional<Eigen::Matrix3d> hessianAt(const TsdfVolume& vol, const Eigen::Vector3i& v,
                                         float w_min);

/// A selected key voxel.
struct KeyVoxel {
  Eigen::Vector3i voxel = Eigen::Vector3i::Zero();  ///< global index in the source volume
  double det = 0.0;  ///< det of the Hessian in voxel units (H / voxel_size)
};

/// Key voxels of a blob of `vol`: blob voxels whose det(Hessian) is a strict local max or min over
/// their 26 neighbours (all of which must have a Hessian; ties broken by index), with
/// |det| >= params.min_abs_det; the params.max_key_voxels largest |det| (ties by index), in that
/// order. `blob` holds global voxel indices (duplicates are ignored). Throws planesdf::Error when
/// the blob's bounding box plus a 3-voxel margin exceeds params.max_box_voxels.
std::vector<KeyVoxel> keyVoxels(const TsdfVolume& vol, const std::vector<Eigen::Vector3i>& blob,
                                const Config& cfg, const ValidationParams& params = {});

/// λ ranges of the three sub-histograms (bin edges along λ), in normalised eigenvalue units.
struct LambdaRanges {
  std::array<double, 3> min{};
  std::array<double, 3> max{};
};

/// A key voxel's shape feature and the λ ranges it was binned with.
struct VoxelFeature {
  Eigen::VectorXd values;  ///< featureSize(cfg) values: [h_1 | h_2 | h_3 | s]
  LambdaRanges ranges;
};

/// The SOURCE feature at `v0`: λ ranges from its own neighbourhood. Empty when a voxel of the
/// 3x3x3 neighbourhood has no Hessian (see hessianAt). Throws planesdf::Error on invalid
/// validation parameters of `cfg` (as validateBlob).
std::optional<VoxelFeature> featureAt(const TsdfVolume& vol, const Eigen::Vector3i& v0,
                                      const Config& cfg, const ValidationParams& params = {});

/// The TARGET feature at `v0`, binned with the source's λ `ranges` (returned unchanged in the
/// result). `R_ref_vol` rotates this volume's directions into the reference (source) frame
/// before binning: pass T_target_source.linear().transpose(). Empty as for the source feature.
std::optional<VoxelFeature> featureAt(
    const TsdfVolume& vol, const Eigen::Vector3i& v0, const LambdaRanges& ranges, const Config& cfg,
    const Eigen::Matrix3d& R_ref_vol = Eigen::Matrix3d::Identity(),
    const ValidationParams& params = {});

/// sim = 1 / (1 + alpha ‖f - g‖₂) ∈ (0, 1]. Throws planesdf::Error when the sizes differ.
double similarity(const Eigen::VectorXd& f, const Eigen::VectorXd& g, double alpha);

/// The observed voxels (weight > 0 and >= w_min) of `vol` in the given (i, j) columns with
/// k in [k_min, k_max]: the voxel blob of a set of 2D cells (the brief's blobs). Columns are
/// global voxel columns (cell (x, y) of a GridGeometry g is column (g.i0 + x, g.j0 + y)).
/// Ordered column by column (input order), k ascending; duplicate columns are ignored.
std::vector<Eigen::Vector3i> blobVoxelsFromColumns(const TsdfVolume& vol,
                                                   const std::vector<Eigen::Vector2i>& columns,
                                                   int k_min, int k_max, float w_min);

/// The score of one key voxel.
struct KeyVoxelScore {
  Eigen::Vector3i voxel = Eigen::Vector3i::Zero();         ///< source voxel
  Eigen::Vector3i target_voxel = Eigen::Vector3i::Zero();  ///< corresponding target voxel
  double det = 0.0;                                        ///< as KeyVoxel::det
  bool scored = false;      ///< false: the target neighbourhood is unobserved
  double similarity = 0.0;  ///< valid when scored
};

/// The 3D validation of one blob.
struct BlobValidation {
  enum class Verdict {
    Changed,    ///< mean similarity < cfg.delta_blob
    Unchanged,  ///< mean similarity >= cfg.delta_blob
    Unknown     ///< fewer than ValidationParams::min_scored key voxels could be scored: fall
                ///< back to the height-map verdict
  };
  int key_voxels = 0;            ///< key voxels found in the blob
  int scored = 0;                ///< key voxels with an observed target neighbourhood
  double mean_similarity = 0.0;  ///< mean of `similarities` (0 when none)
  Verdict verdict = Verdict::Unknown;
  std::vector<double> similarities;  ///< scores of the scored key voxels, in key-voxel order
  std::vector<KeyVoxelScore> keys;   ///< every key voxel (KeyVoxel order), scored or not
};

/// "changed", "unchanged" or "unknown".
const char* toString(BlobValidation::Verdict v);

/// Validates a source blob against the target volume. `blob_voxels` are global voxel indices of
/// `source` (e.g. blobVoxelsFromColumns); `T_target_source` maps source plane-local coordinates
/// into target plane-local coordinates. Key voxels as keyVoxels(); each is scored with
/// similarity(featureAt(source, v0), featureAt(target, v0', source ranges, R⁻¹), cfg.alpha) where
/// v0' is the target voxel containing T_target_source * centre(v0). Hessians of the source are
/// computed once over the blob's bounding box; key voxels are scored in parallel (cfg.threads,
/// 0 = all cores), deterministically. Throws planesdf::Error when the voxel sizes differ,
/// T_target_source is not finite, a validation parameter of `cfg` is invalid (bins outside
/// [1, 64], sdf_sigma_voxels <= 0, alpha < 0) or the blob's box is too large (see keyVoxels).
BlobValidation validateBlob(const TsdfVolume& source, const TsdfVolume& target,
                            const Pose& T_target_source,
                            const std::vector<Eigen::Vector3i>& blob_voxels, const Config& cfg,
                            const ValidationParams& params = {});

}  // namespace planesdf
