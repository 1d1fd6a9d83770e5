// `face-reenact devices`: the Vulkan devices this machine offers and which one is used.
// `face-reenact bench render`: cost of one G-buffer render S(P) per pyramid level, GPU stages
// (timestamp queries) next to the CPU reference renderer in the same run.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "command_registry.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/live/usb_cameras.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/gpu/cpu_renderer.h"
#include "face_reenact/gpu/renderer.h"
#include "face_reenact/model/model_file.h"

namespace face_reenact::cli {
namespace {

using namespace face_reenact::gpu;

std::string human_bytes(uint64_t b) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.1f GiB", static_cast<double>(b) / (1024.0 * 1024.0 * 1024.0));
  return buf;
}

// The RGB-D cameras on USB (live/usb_cameras.h), for `devices` and `devices --cameras`.
void print_rgbd_cameras(bool json) {
  std::string error;
  const auto cameras = live::list_usb_rgbd_cameras(&error);
  if (json) {
    nlohmann::json doc = {{"cameras", nlohmann::json::array()}, {"error", error.empty() ? nlohmann::json() : nlohmann::json(error)}};
    for (const auto& c : cameras) {
      char id[16];
      std::snprintf(id, sizeof id, "%04x:%04x", c.vendor_id, c.product_id);
      doc["cameras"].push_back({{"model", c.model}, {"usb_id", id}, {"bus", c.bus}, {"address", c.address}});
    }
    std::printf("%s\n", doc.dump(2).c_str());
    return;
  }
  if (!error.empty()) {
    std::printf("RGB-D cameras on USB: unknown, %s\n", error.c_str());
  } else if (cameras.empty()) {
    std::printf("RGB-D cameras on USB: none (PrimeSense, Asus Xtion, Carmine or Kinect; an OpenNI input waits for one)\n");
  } else {
    std::printf("RGB-D cameras on USB (an OpenNI input opens the first: openni, or openni:URI):\n");
    for (const auto& c : cameras) std::printf("  %s\n", c.Describe().c_str());
  }
}

void run_devices(const std::string& device, bool json, bool cameras_only) {
  if (cameras_only) return print_rgbd_cameras(json);
  const auto devices = Context::enumerate_devices(device);
  if (json) {
    nlohmann::json doc = nlohmann::json::array();
    for (const auto& d : devices) {
      nlohmann::json heaps = nlohmann::json::array();
      for (const auto& h : d.heaps) heaps.push_back({{"size_bytes", h.size_bytes}, {"device_local", h.device_local}});
      doc.push_back({{"index", d.index},
                     {"name", d.name},
                     {"type", d.type},
                     {"api_version", d.api_version},
                     {"driver_name", d.driver_name},
                     {"driver_info", d.driver_info},
                     {"heaps", heaps},
                     {"usable", d.usable},
                     {"why_unusable", d.why_unusable},
                     {"selected", d.would_pick}});
    }
    std::printf("%s\n", doc.dump(2).c_str());
    return;
  }
  if (devices.empty()) {
    std::printf("no Vulkan devices\n");
    return;
  }
  for (const auto& d : devices) {
    std::printf("%s [%u] %s\n", d.would_pick ? "*" : " ", d.index, d.name.c_str());
    std::printf("      type %s, Vulkan %s, driver %s (%s)\n", d.type.c_str(), d.api_version.c_str(), d.driver_name.c_str(),
                d.driver_info.c_str());
    for (size_t h = 0; h < d.heaps.size(); ++h) {
      std::printf("      heap %zu: %s%s\n", h, human_bytes(d.heaps[h].size_bytes).c_str(),
                  d.heaps[h].device_local ? " device-local" : "");
    }
    if (!d.usable) std::printf("      unusable: %s\n", d.why_unusable.c_str());
  }
  bool any = false;
  for (const auto& d : devices) any = any || d.would_pick;
  std::printf(any ? "* = the device face-reenact uses (override: --device or FR_VULKAN_DEVICE)\n"
                  : "no device matches the selection\n");
  print_rgbd_cameras(false);
}

struct BenchArgs {
  std::string model;
  std::string device;
  int iterations = 20;
  bool json = false;
  bool validation = false;
};

double median(std::vector<double> v) {
  if (v.empty()) return -1;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

void run_bench_render(const BenchArgs& a) {
  if (a.iterations < 1 || a.iterations > 100000) throw Error("--iterations must be in 1..100000");
  const std::string model_path = resolve_model_path(a.model);
  const RenderModel model = RenderModel::FromFaceModel(load_face_model(model_path));
  Context::Options co;
  co.device = a.device;
  co.enable_validation = a.validation;
  Context context(co);
  Renderer renderer(context, model);
  Renderer::Options no_timestamps;
  no_timestamps.timestamps = false;
  Renderer fast(context, model, no_timestamps);
  CpuRenderer cpu(model);

  // A close-up frontal face with a mild expression under ambient + directional light.
  FaceParameters p = frontal_pose(0.5f);
  p.delta = Eigen::VectorXf::Constant(model.expression_basis.cols(), 0.1f);
  p.euler += Eigen::Vector3f(0.05f, 0.15f, 0.0f);
  for (int c = 0; c < 3; ++c) {
    p.gamma[c * 9 + 2] = -0.4f;  // light from the camera side
    p.gamma[c * 9 + 1] = -0.2f;  // and from above (y down)
  }
  const PinholeCamera full;
  nlohmann::json levels = nlohmann::json::array();
  for (int level = 0; level < 3; ++level) {
    const PinholeCamera cam = full.Downsampled(level);
    renderer.render(p, cam);  // warm-up: pipelines, targets, draw list
    std::vector<double> model_ms, shade_ms, raster_ms, gpu_ms, wall_ms;
    size_t covered = 0;
    for (int i = 0; i < a.iterations; ++i) {
      const RenderTimings t = renderer.render(p, cam);
      model_ms.push_back(t.model_ms);
      shade_ms.push_back(t.shade_ms);
      raster_ms.push_back(t.raster_ms);
      gpu_ms.push_back(t.gpu_total_ms);
      wall_ms.push_back(t.wall_ms);
    }
    covered = renderer.read_gbuffer().covered_count();
    // Wall time without timestamp queries (on lavapipe each query flushes the rasteriser).
    std::vector<double> plain_wall_ms;
    fast.render(p, cam);
    for (int i = 0; i < a.iterations; ++i) plain_wall_ms.push_back(fast.render(p, cam).wall_ms);
    std::vector<double> cpu_model, cpu_shade, cpu_raster, cpu_total, cpu_raster_geometry;
    GBuffer kept, kept_geometry;  // as the per-frame callers (the tracker, the compositor) draw: into a kept buffer
    RenderOptions geometry;       // as the tracker's syntheses on colour-only input draw: no normals, no colours
    geometry.normals = false;
    geometry.colors = false;
    for (int i = 0; i < a.iterations; ++i) {
      CpuRenderTimes t;
      const VertexState state = cpu.evaluate(p, &t);
      auto raster_start = std::chrono::steady_clock::now();
      cpu.rasterize(state, cam, RenderOptions{}, &kept);
      t.raster_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - raster_start).count();
      raster_start = std::chrono::steady_clock::now();
      cpu.rasterize(state, cam, geometry, &kept_geometry);
      cpu_raster_geometry.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - raster_start).count());
      cpu_model.push_back(t.model_ms);
      cpu_shade.push_back(t.shade_ms);
      cpu_raster.push_back(t.raster_ms);
      cpu_total.push_back(t.model_ms + t.shade_ms + t.raster_ms);
    }
    // The ratio uses the host wall time of a render without timestamps: the number a caller
    // waits for (GPU timestamps undercount on lavapipe, see docs/renderer.md).
    const double g_total = median(plain_wall_ms), c_total = median(cpu_total);
    levels.push_back({{"level", level},
                      {"width", cam.width},
                      {"height", cam.height},
                      {"covered_pixels", covered},
                      {"gpu",
                       {{"model_ms", median(model_ms)},
                        {"shade_ms", median(shade_ms)},
                        {"raster_ms", median(raster_ms)},
                        {"total_ms", median(gpu_ms)},
                        {"wall_ms", median(wall_ms)},
                        {"wall_no_timestamps_ms", median(plain_wall_ms)}}},
                      {"cpu",
                       {{"model_ms", median(cpu_model)},
                        {"shade_ms", median(cpu_shade)},
                        {"raster_ms", median(cpu_raster)},
                        {"raster_geometry_ms", median(cpu_raster_geometry)},
                        {"total_ms", c_total}}},
                      {"gpu_cpu_ratio", c_total > 0 ? g_total / c_total : -1}});
  }
  nlohmann::json doc = {{"device", context.device_info().name},
                        {"device_type", context.device_info().type},
                        {"model", model_path},
                        {"vertices", model.num_vertices()},
                        {"triangles", model.num_triangles()},
                        {"drawn_triangles", drawn_triangles(model, RenderOptions{}).size()},
                        {"iterations", a.iterations},
                        {"statistic", "median"},
                        {"levels", levels}};
  if (a.json) {
    std::printf("%s\n", doc.dump(2).c_str());
    return;
  }
  std::printf("render S(P): %s (%s), %d vertices, %zu of %d triangles drawn (skin), median of %d\n",
              context.device_info().name.c_str(), context.device_info().type.c_str(), model.num_vertices(),
              static_cast<size_t>(doc["drawn_triangles"]), model.num_triangles(), a.iterations);
  std::printf("%-9s %8s | %7s %7s %7s %7s %7s %7s | %7s %7s %7s %7s %7s | %7s\n", "level", "pixels", "model", "shade",
              "raster", "gpu", "wall", "wall-ts", "model", "shade", "raster", "geom", "cpu", "gpu/cpu");
  std::printf("%-9s %8s | %47s | %39s | %7s\n", "", "covered", "GPU ms: stage timestamps, host wall with/without",
              "CPU ms (geom: no normals, colours)", "walls");
  for (const auto& l : levels) {
    const std::string size = std::to_string(int(l["width"])) + "x" + std::to_string(int(l["height"]));
    std::printf("%-9s %8zu | %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f | %7.3f %7.3f %7.3f %7.3f %7.3f | %7.3f\n", size.c_str(),
                static_cast<size_t>(l["covered_pixels"]), double(l["gpu"]["model_ms"]), double(l["gpu"]["shade_ms"]),
                double(l["gpu"]["raster_ms"]), double(l["gpu"]["total_ms"]), double(l["gpu"]["wall_ms"]),
                double(l["gpu"]["wall_no_timestamps_ms"]),
                double(l["cpu"]["model_ms"]), double(l["cpu"]["shade_ms"]), double(l["cpu"]["raster_ms"]),
                double(l["cpu"]["raster_geometry_ms"]), double(l["cpu"]["total_ms"]), double(l["gpu_cpu_ratio"]));
  }
}

void add_gpu_commands(CLI::App& app) {
  auto devices_json = std::make_shared<bool>(false);
  auto devices_select = std::make_shared<std::string>();
  auto devices_cameras = std::make_shared<bool>(false);
  CLI::App* devices = app.add_subcommand(
      "devices", "List the Vulkan devices and the one face-reenact would use, and the RGB-D cameras on USB");
  devices->add_flag("--json", *devices_json, "Machine-readable output");
  devices->add_flag("--cameras", *devices_cameras, "Only the RGB-D cameras on USB (PrimeSense, Xtion, Kinect)");
  devices->add_option("--device", *devices_select, "Selection to evaluate (name substring or index; default FR_VULKAN_DEVICE)");
  devices->callback([devices_json, devices_select, devices_cameras] {
    run_devices(*devices_select, *devices_json, *devices_cameras);
  });

  CLI::App* bench = get_or_add_subcommand(app, "bench", "Measure the cost of pipeline stages");
  auto args = std::make_shared<BenchArgs>();
  CLI::App* render = bench->add_subcommand("render", "G-buffer render S(P) per pyramid level: GPU stages vs CPU reference");
  render->add_option("--model", args->model, "Face model file (default: the installed/generated face-model.frm)");
  render->add_option("--device", args->device, "Vulkan device: name substring or index (default FR_VULKAN_DEVICE or automatic)");
  render->add_option("--iterations", args->iterations, "Timed renders per level and implementation")->check(CLI::Range(1, 100000));
  render->add_flag("--json", args->json, "Machine-readable output");
  render->add_flag("--validation", args->validation, "Enable the Vulkan validation layer (slower)");
  render->callback([args] { run_bench_render(*args); });
}

}  // namespace

FR_REGISTER_COMMANDS(gpu, add_gpu_commands);

}  // namespace face_reenact::cli
