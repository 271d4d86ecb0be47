// Reading and writing point clouds: a real mOSD scene (PCD binary_compressed, 307200 points) and
// a 300k-point PLY written by the benchmark. Run:
//   build/bin/bench_io --benchmark_repetitions=10 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "planesdf/io/pcd.hpp"
#include "planesdf/io/ply.hpp"

namespace {

std::string mosdScene() {
  const char* env = std::getenv("PLANESDF_SHARED_DIR");
  return std::string(env ? env : PLANESDF_SHARED_DIR) + "/data/mosd/scenes/test31.pcd";
}

std::string tempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() / name).string();
}

void BM_ReadPcdMosd(benchmark::State& state) {
  const std::string path = mosdScene();
  for (auto _ : state) {
    auto cloud = planesdf::io::readPcd(path);
    benchmark::DoNotOptimize(cloud.points.data());
  }
  state.SetItemsProcessed(state.iterations() * 307200);
}
BENCHMARK(BM_ReadPcdMosd)->Unit(benchmark::kMillisecond);

void BM_WritePcdCompressed(benchmark::State& state) {
  const auto cloud = planesdf::io::readPcd(mosdScene());
  const std::string out = tempPath("planesdf_bench_io.pcd");
  for (auto _ : state)
    planesdf::io::writePcd(out, cloud, planesdf::io::PcdFormat::BinaryCompressed);
  std::filesystem::remove(out);
}
BENCHMARK(BM_WritePcdCompressed)->Unit(benchmark::kMillisecond);

void BM_ReadPlyBinary(benchmark::State& state) {
  planesdf::PointCloud cloud;
  for (int i = 0; i < 300000; ++i)
    cloud.points.emplace_back(0.001f * static_cast<float>(i % 640),
                              0.002f * static_cast<float>(i / 640), 1.0f);
  cloud.width = static_cast<std::uint32_t>(cloud.points.size());
  cloud.addField("object_id", planesdf::ScalarType::Int32, 3.0);
  const std::string path = tempPath("planesdf_bench_io.ply");
  planesdf::io::writePly(path, cloud);
  for (auto _ : state) {
    auto c = planesdf::io::readPly(path);
    benchmark::DoNotOptimize(c.points.data());
  }
  state.SetItemsProcessed(state.iterations() * 300000);
  std::filesystem::remove(path);
}
BENCHMARK(BM_ReadPlyBinary)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
