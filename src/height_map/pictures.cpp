// PNG pictures of height maps and object maps (OpenCV imgproc for drawing, imgcodecs for
// encoding; the bytes go out through io::writeFileAtomic).

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ostream>
#include <string>
#include <vector>

#include "planesdf/error.hpp"
#include "planesdf/height_map.hpp"
#include "planesdf/io/atomic_file.hpp"

namespace planesdf {
namespace {

const cv::Scalar kWhite(255, 255, 255);
const cv::Scalar kBlack(0, 0, 0);
const cv::Vec3b kFlatColor(80, 80, 80);
const cv::Vec3b kUnobservedColor(0, 0, 0);
constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;
/// Object-map pictures number the objects of at least this many cells, at most kMaxLabels.
constexpr int kLabelMinCells = 20;
constexpr std::size_t kMaxLabels = 100;
constexpr double kFontScale = 0.42;

void putLabel(cv::Mat& img, const std::string& text, cv::Point at, const cv::Scalar& color) {
  cv::putText(img, text, at, kFont, kFontScale, color, 1, cv::LINE_AA);
}

/// Text with a dark outline, centred on `centre` (readable on any colour).
void putOutlinedCentred(cv::Mat& img, const std::string& text, cv::Point centre) {
  int baseline = 0;
  const cv::Size sz = cv::getTextSize(text, kFont, 0.5, 1, &baseline);
  const cv::Point at(centre.x - sz.width / 2, centre.y + sz.height / 2);
  cv::putText(img, text, at, kFont, 0.5, kBlack, 3, cv::LINE_AA);
  cv::putText(img, text, at, kFont, 0.5, kWhite, 1, cv::LINE_AA);
}

/// 256 BGR colours of the turbo colour map.
std::vector<cv::Vec3b> turboTable() {
  cv::Mat ramp(1, 256, CV_8UC1);
  for (int i = 0; i < 256; ++i) ramp.at<std::uint8_t>(0, i) = static_cast<std::uint8_t>(i);
  cv::Mat colored;
  cv::applyColorMap(ramp, colored, cv::COLORMAP_TURBO);
  std::vector<cv::Vec3b> table(256);
  for (int i = 0; i < 256; ++i) table[static_cast<std::size_t>(i)] = colored.at<cv::Vec3b>(0, i);
  return table;
}

cv::Vec3b heightColor(float h, float max_height, float flat_below,
                      const std::vector<cv::Vec3b>& turbo) {
  if (h == kUnobserved || h < 0.0f) return kUnobservedColor;
  if (h <= flat_below) return kFlatColor;
  const float t = std::clamp(h / max_height, 0.0f, 1.0f);
  return turbo[static_cast<std::size_t>(std::lround(t * 255.0f))];
}

/// BGR of hue/saturation/value in [0, 1].
cv::Vec3b hsvToBgr(double hue, double sat, double val) {
  const double h6 = hue * 6.0;
  const int sector = static_cast<int>(std::floor(h6)) % 6;
  const double f = h6 - std::floor(h6);
  const double p = val * (1 - sat), q = val * (1 - sat * f), t = val * (1 - sat * (1 - f));
  double r = val, g = t, b = p;
  switch (sector) {
    case 1:
      r = q, g = val, b = p;
      break;
    case 2:
      r = p, g = val, b = t;
      break;
    case 3:
      r = p, g = q, b = val;
      break;
    case 4:
      r = t, g = p, b = val;
      break;
    case 5:
      r = val, g = p, b = q;
      break;
    default:
      break;
  }
  const auto u8 = [](double c) { return static_cast<std::uint8_t>(std::lround(c * 255.0)); };
  return cv::Vec3b(u8(b), u8(g), u8(r));
}

/// A distinct, bright colour per label (golden-ratio hue steps, varying saturation).
cv::Vec3b labelColor(int label) {
  const double hue = std::fmod(0.12 + label * 0.6180339887, 1.0);
  const double sat = 0.55 + 0.2 * (label % 3);
  return hsvToBgr(hue, sat, 1.0);
}

/// Paints cell colours into the top-left of `img`, v upward, s pixels per cell.
template <class ColorOf>
void paintCells(cv::Mat& img, const GridGeometry& g, int s, ColorOf&& color_of) {
  for (int y = 0; y < g.height; ++y) {
    const int row0 = (g.height - 1 - y) * s;
    for (int x = 0; x < g.width; ++x) {
      const cv::Vec3b c = color_of(x, y);
      for (int r = row0; r < row0 + s; ++r) {
        cv::Vec3b* px = img.ptr<cv::Vec3b>(r) + x * s;
        std::fill(px, px + s, c);
      }
    }
  }
}

std::string format(const char* fmt, double a) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), fmt, a);
  return buf;
}

void drawCaption(cv::Mat& img, const GridGeometry& g, int s, const std::string& extra,
                 const cv::Scalar& color) {
  const int y0 = img.rows - kPictureCaptionHeight;
  putLabel(img, "u: right, v: up (plane seen from its free side)", cv::Point(6, y0 + 16), color);
  putLabel(img,
           format("cell %.1f mm, ", g.cell_size * 1000.0) + std::to_string(g.width) + " x " +
               std::to_string(g.height) + " cells, " + std::to_string(s) + " px/cell" + extra,
           cv::Point(6, y0 + 33), color);
}

/// Tick spacing (cm) giving at most 6 intervals over [0, max_cm].
double tickStepCm(double max_cm) {
  for (double step : {0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0})
    if (max_cm / step <= 6.0) return step;
  return std::ceil(max_cm / 6.0 / 100.0) * 100.0;
}

void drawHeightLegend(cv::Mat& img, int x0, float max_height, float flat_below,
                      const std::vector<cv::Vec3b>& turbo) {
  putLabel(img, "height above plane", cv::Point(x0 + 10, 20), kBlack);
  const int bar_x = x0 + 14, bar_w = 22, bar_top = 36, bar_h = 220;
  for (int r = 0; r < bar_h; ++r) {
    const float h = max_height * static_cast<float>(bar_h - 1 - r) / static_cast<float>(bar_h - 1);
    const cv::Vec3b c = turbo[static_cast<std::size_t>(std::lround(h / max_height * 255.0f))];
    cv::line(img, cv::Point(bar_x, bar_top + r), cv::Point(bar_x + bar_w - 1, bar_top + r),
             cv::Scalar(c[0], c[1], c[2]));
  }
  cv::rectangle(img, cv::Rect(bar_x - 1, bar_top - 1, bar_w + 2, bar_h + 2), kBlack);
  const double max_cm = max_height * 100.0;
  const double step = tickStepCm(max_cm);
  for (double cm = 0.0; cm <= max_cm + 1e-9; cm += step) {
    const int r = bar_top + static_cast<int>(std::lround((1.0 - cm / max_cm) * (bar_h - 1)));
    cv::line(img, cv::Point(bar_x + bar_w, r), cv::Point(bar_x + bar_w + 5, r), kBlack);
    putLabel(img, format(step < 1.0 ? "%.1f cm" : "%.0f cm", cm),
             cv::Point(bar_x + bar_w + 9, r + 5), kBlack);
  }
  const int sy = bar_top + bar_h + 16;
  cv::rectangle(img, cv::Rect(bar_x, sy, bar_w, 14),
                cv::Scalar(kFlatColor[0], kFlatColor[1], kFlatColor[2]), cv::FILLED);
  putLabel(img,
           flat_below > 0.0f ? format("<= %.1f cm: flat", flat_below * 100.0) : "0: flat / free",
           cv::Point(bar_x + bar_w + 9, sy + 12), kBlack);
  cv::rectangle(img, cv::Rect(bar_x, sy + 22, bar_w, 14), kBlack, cv::FILLED);
  putLabel(img, "-1: unobserved", cv::Point(bar_x + bar_w + 9, sy + 34), kBlack);
  putLabel(img, "above top: top colour", cv::Point(bar_x, sy + 56), kBlack);
}

cv::Mat emptyPicture(const std::string& what) {
  cv::Mat img(60, kPictureMinWidth, CV_8UC3, cv::Scalar(255, 255, 255));
  putLabel(img, "empty " + what + " (no allocated blocks)", cv::Point(10, 35), kBlack);
  return img;
}

void writePng(const std::string& path, const cv::Mat& img) {
  std::vector<std::uint8_t> buf;
  try {
    if (!cv::imencode(".png", img, buf)) throw Error(path, "PNG encoding failed");
  } catch (const cv::Exception& e) {
    throw Error(path, std::string("PNG encoding failed: ") + e.what());
  }
  io::writeFileAtomic(path, [&](std::ostream& out) {
    out.write(reinterpret_cast<const char*>(buf.data()), static_cast<std::streamsize>(buf.size()));
  });
}

}  // namespace

int picturePixelsPerCell(const GridGeometry& g) {
  if (g.empty()) return 1;
  int s = std::clamp((400 + g.width - 1) / g.width, 1, 16);
  if (g.height * s > 4000) s = std::max(1, 4000 / g.height);
  return s;
}

void writeHeightMapPng(const std::string& path, const HeightMap& hm, float max_height,
                       float flat_below) {
  if (!(max_height > 0.0f) || !std::isfinite(max_height))
    throw Error(path, "height map picture: max_height must be positive and finite, got " +
                          std::to_string(max_height));
  if (!(flat_below >= 0.0f))
    throw Error(path,
                "height map picture: flat_below must be >= 0, got " + std::to_string(flat_below));
  if (hm.empty() || hm.heights.size() != hm.numCells()) {
    if (!hm.empty()) throw Error(path, "height map has the wrong number of cells");
    writePng(path, emptyPicture("height map"));
    return;
  }
  const int s = picturePixelsPerCell(hm);
  const int map_w = hm.width * s, map_h = hm.height * s;
  cv::Mat img(std::max(map_h, kPictureLegendMinHeight) + kPictureCaptionHeight,
              map_w + kPictureLegendWidth, CV_8UC3, kWhite);
  const std::vector<cv::Vec3b> turbo = turboTable();
  paintCells(img, hm, s,
             [&](int x, int y) { return heightColor(hm.at(x, y), max_height, flat_below, turbo); });
  drawHeightLegend(img, map_w, max_height, flat_below, turbo);
  drawCaption(img, hm, s, "", kBlack);
  writePng(path, img);
}

void writeObjectMapPng(const std::string& path, const ObjectMap& om) {
  if (om.empty() || om.labels.size() != om.numCells()) {
    if (!om.empty()) throw Error(path, "object map has the wrong number of cells");
    writePng(path, emptyPicture("object map"));
    return;
  }
  const int s = picturePixelsPerCell(om);
  const int map_w = om.width * s, map_h = om.height * s;
  cv::Mat img(map_h + kPictureCaptionHeight, std::max(map_w, kPictureMinWidth), CV_8UC3, kBlack);
  paintCells(img, om, s, [&](int x, int y) {
    const int l = om.at(x, y);
    return l == 0 ? cv::Vec3b(0, 0, 0) : labelColor(l);
  });
  // Numbers on the objects that can carry one: at least kLabelMinCells cells, the largest
  // kMaxLabels of them (a room's maps hold thousands of noise specks; outlined text costs
  // about a millisecond a label).
  std::vector<const ObjectInfo*> labelled;
  for (const ObjectInfo& o : om.objects)
    if (o.area >= kLabelMinCells) labelled.push_back(&o);
  std::stable_sort(labelled.begin(), labelled.end(),
                   [](const ObjectInfo* a, const ObjectInfo* b) { return a->area > b->area; });
  if (labelled.size() > kMaxLabels) labelled.resize(kMaxLabels);
  for (const ObjectInfo* op : labelled) {
    const ObjectInfo& o = *op;
    const double cx = (o.centroid.x() / om.cell_size - om.i0) * s;
    const double cy = (om.height - (o.centroid.y() / om.cell_size - om.j0)) * s;
    putOutlinedCentred(
        img, std::to_string(o.label),
        cv::Point(static_cast<int>(std::lround(cx)), static_cast<int>(std::lround(cy))));
  }
  cv::line(img, cv::Point(0, map_h), cv::Point(img.cols - 1, map_h), cv::Scalar(128, 128, 128));
  drawCaption(img, om, s, ", " + std::to_string(om.numObjects()) + " objects", kWhite);
  writePng(path, img);
}

void writeMaskPng(const std::string& path, const Mask2D& mask, const HeightMap* background,
                  const std::string& title) {
  if (mask.empty() || mask.cells.size() != mask.numCells()) {
    if (!mask.empty()) throw Error(path, "mask has the wrong number of cells");
    writePng(path, emptyPicture("mask"));
    return;
  }
  const bool with_bg = background != nullptr && background->sameGeometry(mask) &&
                       background->heights.size() == background->numCells();
  const int s = picturePixelsPerCell(mask);
  const int map_w = mask.width * s, map_h = mask.height * s;
  cv::Mat img(map_h + kPictureCaptionHeight + 20, std::max(map_w, kPictureMinWidth), CV_8UC3,
              kBlack);
  paintCells(img, mask, s, [&](int x, int y) {
    if (mask.at(x, y)) return cv::Vec3b(40, 40, 255);  // red (BGR)
    if (!with_bg) return cv::Vec3b(0, 0, 0);
    const float h = background->at(x, y);
    if (h == kUnobserved || h < 0.0f) return cv::Vec3b(0, 0, 0);
    const double t = std::clamp(static_cast<double>(h) / 0.3, 0.0, 1.0);
    const auto g = static_cast<std::uint8_t>(std::lround(70.0 + 150.0 * t));
    return cv::Vec3b(g, g, g);
  });
  cv::line(img, cv::Point(0, map_h), cv::Point(img.cols - 1, map_h), cv::Scalar(128, 128, 128));
  putLabel(img, title + ": " + std::to_string(mask.count()) + " cells in red",
           cv::Point(6, map_h + 16), kWhite);
  cv::Mat body = img(cv::Rect(0, 20, img.cols, img.rows - 20));
  drawCaption(body, mask, s, with_bg ? ", grey: height (black unobserved)" : "", kWhite);
  writePng(path, img);
}

}  // namespace planesdf
