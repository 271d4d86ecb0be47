#pragma once
/// \file height_map.hpp
/// The 2D stage of a PlaneSDF (paper §III-A; design.md, "Pipeline"):
/// per plane, a height map at voxel resolution (max surface height above the plane per cell,
/// 0 = observed flat/free, -1 = unobserved), the object map (8-connected components of cells
/// higher than h_obj), small reusable 2D mask helpers for the change stage, and PNG pictures.
///
/// Every grid here shares one geometry (GridGeometry): cell (x, y) is the TSDF column of global
/// voxel indices (i0 + x, j0 + y), so it covers [(i0 + x) * cell_size, (i0 + x + 1) * cell_size)
/// along u and the same along v with j0 + y, in the plane's local frame (see tsdf.hpp). Storage
/// is row-major, x fastest: cells[x + width * y].

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "planesdf/config.hpp"
#include "planesdf/tsdf.hpp"

namespace planesdf {

/// Height of a cell with no observation (the paper's -1).
constexpr float kUnobserved = -1.0f;

/// Geometry of a 2D grid over a plane: size in cells, the global voxel column (i0, j0) of cell
/// (0, 0) and the cell size in metres (= the TSDF voxel size).
struct GridGeometry {
  int width = 0;           ///< cells along u
  int height = 0;          ///< cells along v
  int i0 = 0;              ///< global voxel index (u) of cell x = 0
  int j0 = 0;              ///< global voxel index (v) of cell y = 0
  double cell_size = 0.0;  ///< m

  /// Number of cells (width * height).
  std::size_t numCells() const {
    return static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  }
  bool empty() const { return width <= 0 || height <= 0; }
  bool inBounds(int x, int y) const { return x >= 0 && y >= 0 && x < width && y < height; }
  /// Row-major index of cell (x, y); requires inBounds(x, y).
  std::size_t index(int x, int y) const {
    return static_cast<std::size_t>(y) * static_cast<std::size_t>(width) +
           static_cast<std::size_t>(x);
  }
  /// Centre of cell (x, y) in plane-local (u, v), metres.
  Eigen::Vector2d cellCenter(int x, int y) const {
    return Eigen::Vector2d((i0 + x + 0.5) * cell_size, (j0 + y + 0.5) * cell_size);
  }
  /// The cell containing plane-local (u, v) (floor); may be out of bounds, check inBounds().
  /// Non-finite or absurdly far (u, v) give -1 (out of bounds).
  Eigen::Vector2i cellOf(const Eigen::Vector2d& uv) const {
    return Eigen::Vector2i(cellIndex(uv.x(), i0), cellIndex(uv.y(), j0));
  }
  /// floor(w / cell_size) - origin; -1 when |w / cell_size| >= 5e8 or not finite. An integer
  /// floor (truncate, minus one where that rounded up): the x86-64 baseline has no rounding
  /// instruction, and the hot loops of detection call this per point and per cell.
  int cellIndex(double w, int origin) const {
    const double q = w / cell_size;
    if (!(std::abs(q) < 5e8)) return -1;
    const int i = static_cast<int>(q);
    return i - (q < static_cast<double>(i) ? 1 : 0) - origin;
  }
  /// True when both grids have the same size, origin and cell size.
  bool sameGeometry(const GridGeometry& o) const {
    return width == o.width && height == o.height && i0 == o.i0 && j0 == o.j0 &&
           cell_size == o.cell_size;
  }
  /// The geometry alone (drops the derived struct's data).
  const GridGeometry& geometry() const { return *this; }
};

/// Max surface height above the plane per TSDF column.
///
/// heights[index(x, y)] is, in metres:
///  * > 0: the highest surface of the column above the plane (an object, or noise below h_obj:
///    heights in (0, h_obj] are kept as measured and left to the object map's threshold);
///  * 0: observed flat or free (a surface at or slightly below the plane, or free space seen
///    down to the plane);
///  * kUnobserved (-1): nothing known.
struct HeightMap : GridGeometry {
  std::vector<float> heights;  ///< row-major, numCells() values
  /// Per cell, 1 when its height is the top face of an inside voxel under unobserved space
  /// (rule 1 below): what lies above it was never seen. Empty: none is.
  std::vector<std::uint8_t> unseen_above;

  float at(int x, int y) const { return heights[index(x, y)]; }
  bool unseenAbove(int x, int y) const {
    return !unseen_above.empty() && unseen_above[index(x, y)] != 0;
  }
  float& at(int x, int y) { return heights[index(x, y)]; }
  bool observed(int x, int y) const { return at(x, y) != kUnobserved; }
  /// Number of cells that are not kUnobserved.
  std::size_t numObserved() const;
};

/// Largest height map computeHeightMap builds (2^28 cells, 1 GiB of floats).
constexpr std::size_t kMaxHeightMapCells = std::size_t{1} << 28;

/// The height map of `vol` over the (u, v) extent of its allocated blocks (blockBounds), one
/// cell per voxel column. An empty volume gives an empty map (width = height = 0). Throws
/// planesdf::Error when that extent exceeds kMaxHeightMapCells, or when its cells times
/// kHeightMapBytesPerCell exceed the memory limit (Config::memory_limit_mb).
///
/// Per column (i, j), voxels are walked from the top of the allocated band downward; a voxel is
/// *observed* when weight >= cfg.w_min (and > 0); voxels of unallocated blocks are unobserved.
///  1. Surface: the first (highest) of
///     - a zero crossing between vertically adjacent observed voxels k+1 (sdf > 0, free) and k
///       (sdf <= 0): h = (k + 0.5) * vs + vs * sdf_k / (sdf_k - sdf_{k+1}), linear between the
///       two centres;
///     - an observed voxel k with sdf <= 0 directly below an unobserved voxel (or the topmost
///       allocated voxel): h = (k + 1) * vs, its top face (splatted clouds carry no free space).
///     The cell is max(h, 0): crossings slightly below the plane are the plane itself.
///  2. No surface: the cell is 0 when an observed free voxel (sdf > 0) has its centre at
///     h <= cfg.h_obj (free space seen down to the plane), else kUnobserved (free space seen only
///     high up says nothing about what sits low; no observed voxel at all says nothing).
/// Parallel over block columns (cfg.threads, 0 = all CPUs); deterministic.
HeightMap computeHeightMap(const TsdfVolume& vol, const Config& cfg);

/// computeHeightMap over the block columns that meet `window` (u, v in metres; an empty box:
/// all), its grid trimmed from the full one by whole roughness tiles, so computeRoughness
/// gives the full map's tiles there. Cells outside the window but inside the trimmed grid hold
/// their heights. Empty when no block column meets the window.
HeightMap computeHeightMap(const TsdfVolume& vol, const Config& cfg,
                           const Eigen::AlignedBox2d& window);

/// One connected object (or object cluster) of an ObjectMap.
struct ObjectInfo {
  int label = 0;                                       ///< 1..N, its value in ObjectMap::labels
  int area = 0;                                        ///< cells
  Eigen::Vector2i bbox_min = Eigen::Vector2i::Zero();  ///< cell (x, y), inclusive
  Eigen::Vector2i bbox_max = Eigen::Vector2i::Zero();  ///< cell (x, y), inclusive
  float max_height = 0.0f;                             ///< m, over its cells
  Eigen::Vector2d centroid = Eigen::Vector2d::Zero();  ///< mean cell centre, plane-local (u, v)
};

/// Labelled objects on a plane: the 8-connected components of height-map cells > h_obj
/// (speckle components reduced to their opening, see Config::object_min_solidity).
struct ObjectMap : GridGeometry {
  std::vector<int> labels;          ///< row-major; 0 = no object, 1..N = objects[label - 1]
  std::vector<ObjectInfo> objects;  ///< ordered by label (raster order of their first cell)

  int at(int x, int y) const { return labels[index(x, y)]; }
  int numObjects() const { return static_cast<int>(objects.size()); }
  /// The object with `label` (1..numObjects()).
  const ObjectInfo& object(int label) const { return objects[static_cast<std::size_t>(label - 1)]; }
};

/// The object map of `hm`: cells with height > cfg.h_obj, 8-connected, labelled in raster order
/// (row by row, x fastest) of each component's first cell. Same geometry as `hm`. A component
/// with fewer than cfg.object_min_solidity of its cells in erode(mask, 1) is speckle: only its
/// cells within one cell of those (its opening) are objects, as the components they form; a lone
/// cell or a line one or two cells wide, with no 3x3 square, is none.
ObjectMap computeObjectMap(const HeightMap& hm, const Config& cfg);

/// Local roughness of a height map's surface: per square tile of `tile` cells, a robust scale
/// (metres) of the height differences between observed cells `lag` cells apart, both at most
/// `cap` high (objects taller than the noise stay out; the edges of lower ones are a minority of
/// the pairs). A far or grazing surface fused from noisy depth, or reconstructed from it, is
/// bumpy at a few cm; near surfaces are flat to a few mm. The change test scales its threshold
/// with it (compareHeightMaps). Tiles with too few pairs have roughness 0.
struct RoughnessMap {
  int tile = 0;              ///< cells per tile side (0: empty map, roughness 0 everywhere)
  int tiles_x = 0;           ///< tiles along x
  int tiles_y = 0;           ///< tiles along y
  std::vector<float> sigma;  ///< m, row-major over tiles
  /// Roughness at cell (x, y) of the height map it was computed from (0 outside).
  float atCell(int x, int y) const {
    if (tile <= 0 || x < 0 || y < 0) return 0.0f;
    const int tx = x / tile, ty = y / tile;
    if (tx >= tiles_x || ty >= tiles_y) return 0.0f;
    return sigma[static_cast<std::size_t>(ty) * static_cast<std::size_t>(tiles_x) +
                 static_cast<std::size_t>(tx)];
  }
};

/// The roughness of `hm` (cfg.roughness_tile cells per tile, lag 2 cells, cap 2 * cfg.delta_h):
/// per tile, the 75th percentile of |h(a) - h(b)| over horizontal and vertical cell pairs
/// (a, b) two cells apart inside the tile, both observed and at most the cap high, when at least
/// a quarter of the tile's possible pairs qualify; else 0. cfg.roughness_tile = 0 gives an
/// empty map (no scaling).
RoughnessMap computeRoughness(const HeightMap& hm, const Config& cfg);

// --- reusable 2D mask helpers -----------------------------------------------------------------

/// A binary mask over a plane grid (0 = off, anything else = on).
struct Mask2D : GridGeometry {
  std::vector<std::uint8_t> cells;  ///< row-major, numCells() values

  /// An all-off mask with geometry `g`.
  static Mask2D zeros(const GridGeometry& g);
  bool at(int x, int y) const { return cells[index(x, y)] != 0; }
  void set(int x, int y, bool on = true) { cells[index(x, y)] = on ? 1 : 0; }
  /// Number of cells that are on.
  std::size_t count() const;
};

/// Cells of `hm` with height > threshold (e.g. cfg.h_obj: the object cells).
Mask2D maskAbove(const HeightMap& hm, float threshold);

/// Connected components of a mask.
struct Components {
  std::vector<int> labels;  ///< row-major, 0 = off or dropped, 1..count() = areas[label - 1]
  std::vector<int> areas;   ///< cells per component, by label
  int count() const { return static_cast<int>(areas.size()); }
};

/// Connected components of the on-cells of `mask` (8-connected, or 4 when connectivity == 4),
/// labelled 1..N in raster order of their first cell; components with fewer than `min_area`
/// cells are dropped (label 0) and the rest renumbered without gaps.
Components connectedComponents(const Mask2D& mask, int min_area = 1, int connectivity = 8);

/// `mask` without its components smaller than `min_area` cells (8-connected).
Mask2D removeSmallComponents(const Mask2D& mask, int min_area);

/// `mask` dilated by `cells` cells with a square (8-neighbour) element: a cell is on when an
/// on-cell lies within Chebyshev distance `cells`. Cells outside the grid are off. cells <= 0
/// returns the mask unchanged.
Mask2D dilate(const Mask2D& mask, int cells);

/// `mask` eroded by `cells` cells with a square element: a cell is on when every cell within
/// Chebyshev distance `cells` is on. Cells outside the grid are off (a cell nearer the border
/// than `cells` is off). cells <= 0 returns the mask unchanged.
Mask2D erode(const Mask2D& mask, int cells);

// --- pictures ------------------------------------------------------------------------------------
// Layout: the map sits at the top-left corner, each cell a square of s = picturePixelsPerCell()
// pixels (nearest upscaling). Image x = u increasing to the right, v increasing UPWARD (rows
// flipped: the plane seen from its free side), so cell (x, y) covers pixel columns
// [x * s, (x + 1) * s) and rows [(height - 1 - y) * s, (height - y) * s). Below the map (and
// any legend) is a caption band of kPictureCaptionHeight px saying so, with the cell size.
// Written with io::writeFileAtomic; a bad path or a failed encode throws planesdf::Error naming
// `path` and leaves no file. An empty map gives a small picture that says "empty".

/// Height of the caption band under a picture, px.
constexpr int kPictureCaptionHeight = 40;
/// Width of the legend panel right of a height-map picture, px.
constexpr int kPictureLegendWidth = 190;
/// Minimum height of a height-map picture above the caption (room for the legend), px.
constexpr int kPictureLegendMinHeight = 330;
/// Minimum width of an object-map picture (room for the caption), px.
constexpr int kPictureMinWidth = 420;

/// Pixels per cell side in the pictures: ceil(400 / width), in [1, 16], reduced so that the
/// map is at most 4000 px tall.
int picturePixelsPerCell(const GridGeometry& g);

/// PNG of a height map: turbo colour map over [0, max_height] metres (higher values saturate)
/// for heights > flat_below, dark grey (80, 80, 80) for 0 and heights <= flat_below (flat/free:
/// pass cfg.h_obj so that the plane's sub-voxel crossings do not speckle the picture; 0 shows
/// every positive height), black for unobserved, and a white legend panel to the right
/// (kPictureLegendWidth px) with the colour bar labelled in cm and the three categories.
/// Picture size: (width * s + kPictureLegendWidth) x
/// (max(height * s, kPictureLegendMinHeight) + kPictureCaptionHeight).
/// Throws planesdf::Error unless max_height is positive and finite and 0 <= flat_below.
void writeHeightMapPng(const std::string& path, const HeightMap& hm, float max_height = 0.3f,
                       float flat_below = 0.01f);

/// PNG of an object map: a distinct colour per label on black, the label number at each
/// object's centroid. Picture size: max(width * s, kPictureMinWidth) x
/// (height * s + kPictureCaptionHeight).
void writeObjectMapPng(const std::string& path, const ObjectMap& om);

/// PNG of a mask: on-cells red over `background` (when given with the same geometry: grey
/// levels growing with the height, black unobserved; else black), with `title` and the number of
/// on-cells in a line under the map. Picture size: max(width * s, kPictureMinWidth) x
/// (height * s + kPictureCaptionHeight + 20).
void writeMaskPng(const std::string& path, const Mask2D& mask, const HeightMap* background,
                  const std::string& title);

}  // namespace planesdf
