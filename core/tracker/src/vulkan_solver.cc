#include "face_reenact/tracker/vulkan_solver.h"

#include <algorithm>
#include <atomic>
#include <array>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <map>
#include <numeric>
#include <optional>
#include <unordered_map>
#include <utility>

#include "face_reenact/common/error.h"
#include "face_reenact/common/parallel.h"
#include "face_reenact/gpu/buffer.h"
#include "face_reenact/gpu/command.h"
#include "face_reenact/gpu/context.h"
#include "face_reenact/gpu/embedded_shaders.h"
#include "face_reenact/gpu/pipeline.h"
#include "face_reenact/gpu/renderer.h"
#include "face_reenact/gpu/shader_layout.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/common/timing.h"
#include "gauss_newton_loop.h"
#include "tracker_internal.h"

namespace face_reenact::tracker {
namespace {

using Clock = std::chrono::steady_clock;

// Host mirrors of the shaders' blocks (std430; types and rules: gpu/shader_layout.h).

// shaders/tracker_common.glsl, struct TrackParams: the Params buffer of tracker_vertices.comp
// and tracker_evaluate.comp.
struct TrackParams {
  glm::uint num_pixels;                             // P pixel items (8 rows each: 3 point, 2 plane, 3 colour)
  glm::uint num_landmarks;                          // L landmark items (2 rows each)
  glm::uint num_regularizer;                        // R regulariser rows
  glm::uint n;                                      // unknowns (columns of J)
  glm::uint k_id, k_alb, k_exp;                     // solved coefficients per block
  glm::uint o_id, o_alb, o_exp, o_gam, o_rot, o_t;  // column offsets of the blocks
  glm::uint model_id, model_alb, model_exp;         // the model's full coefficient counts
  glm::uint num_vertices;
  glm::uint width;                              // of the pyramid level (pixel index = j * width + i)
  glm::uint regularize_shared;                  // identity/albedo prior rows present
  glm::uint rows;                               // column stride of the column-major J: (8 P + 2 L + R) rounded up to 4
  float s_point, s_plane, s_col, s_lan, s_reg;  // residual pre-scales (energy.cc)
  float fx, fy, cx, cy;
  float s_reg_exp;       // expression prior rows: sqrt(w_reg_expression) / sigma_exp
  float r0[9];           // rotation at the linearisation point, row-major (freezes model normals)
  float w_sparse_exp;    // EnergyOptions::w_expression_sparsity (0 = off)
  float sparse_eps_exp;  // EnergyOptions::expression_sparsity_epsilon
  float pad1, pad2;
};
static_assert(offsetof(TrackParams, num_pixels) == 0);
static_assert(offsetof(TrackParams, num_landmarks) == 4);
static_assert(offsetof(TrackParams, num_regularizer) == 8);
static_assert(offsetof(TrackParams, n) == 12);
static_assert(offsetof(TrackParams, k_id) == 16);
static_assert(offsetof(TrackParams, k_alb) == 20);
static_assert(offsetof(TrackParams, k_exp) == 24);
static_assert(offsetof(TrackParams, o_id) == 28);
static_assert(offsetof(TrackParams, o_alb) == 32);
static_assert(offsetof(TrackParams, o_exp) == 36);
static_assert(offsetof(TrackParams, o_gam) == 40);
static_assert(offsetof(TrackParams, o_rot) == 44);
static_assert(offsetof(TrackParams, o_t) == 48);
static_assert(offsetof(TrackParams, model_id) == 52);
static_assert(offsetof(TrackParams, model_alb) == 56);
static_assert(offsetof(TrackParams, model_exp) == 60);
static_assert(offsetof(TrackParams, num_vertices) == 64);
static_assert(offsetof(TrackParams, width) == 68);
static_assert(offsetof(TrackParams, regularize_shared) == 72);
static_assert(offsetof(TrackParams, rows) == 76);
static_assert(offsetof(TrackParams, s_point) == 80);
static_assert(offsetof(TrackParams, s_plane) == 84);
static_assert(offsetof(TrackParams, s_col) == 88);
static_assert(offsetof(TrackParams, s_lan) == 92);
static_assert(offsetof(TrackParams, s_reg) == 96);
static_assert(offsetof(TrackParams, fx) == 100);
static_assert(offsetof(TrackParams, fy) == 104);
static_assert(offsetof(TrackParams, cx) == 108);
static_assert(offsetof(TrackParams, cy) == 112);
static_assert(offsetof(TrackParams, s_reg_exp) == 116);
static_assert(offsetof(TrackParams, r0) == 120);
static_assert(offsetof(TrackParams, w_sparse_exp) == 156);
static_assert(offsetof(TrackParams, sparse_eps_exp) == 160);
static_assert(offsetof(TrackParams, pad1) == 164);
static_assert(offsetof(TrackParams, pad2) == 168);
static_assert(sizeof(TrackParams) == 172);

// tracker_classify.comp and tracker_landmarks.comp, buffer block Counters.
struct Counters {
  glm::uint pixel_count;
  glm::uint num_point;
  glm::uint num_plane;
  glm::uint num_color;
  glm::uint landmark_count;
  float landmark_weight;
  glm::uint pad[2];
};
static_assert(offsetof(Counters, pixel_count) == 0);
static_assert(offsetof(Counters, num_point) == 4);
static_assert(offsetof(Counters, num_plane) == 8);
static_assert(offsetof(Counters, num_color) == 12);
static_assert(offsetof(Counters, landmark_count) == 16);
static_assert(offsetof(Counters, landmark_weight) == 20);
static_assert(offsetof(Counters, pad) == 24);
static_assert(sizeof(Counters) == 32);

// tracker_classify.comp, push constant block Push.
struct ClassifyPush {
  glm::uint width, height, has_depth, use_point, use_plane, use_color;
  float max_point_distance, min_normal_dot;
  float color_robust_threshold;  // EnergyOptions::color_robust_threshold (0 = off)
  glm::uint color_parts;         // EnergyOptions::color_parts (bit per FacePart)
  glm::uint pixel_sampling;      // EnergyOptions::pixel_sampling
};
static_assert(offsetof(ClassifyPush, width) == 0);
static_assert(offsetof(ClassifyPush, height) == 4);
static_assert(offsetof(ClassifyPush, has_depth) == 8);
static_assert(offsetof(ClassifyPush, use_point) == 12);
static_assert(offsetof(ClassifyPush, use_plane) == 16);
static_assert(offsetof(ClassifyPush, use_color) == 20);
static_assert(offsetof(ClassifyPush, max_point_distance) == 24);
static_assert(offsetof(ClassifyPush, min_normal_dot) == 28);
static_assert(offsetof(ClassifyPush, color_robust_threshold) == 32);
static_assert(offsetof(ClassifyPush, color_parts) == 36);
static_assert(offsetof(ClassifyPush, pixel_sampling) == 40);
static_assert(sizeof(ClassifyPush) == 44);

// tracker_landmarks.comp, push constant block Push.
struct LandmarkPush {
  glm::uint count;
  float near_plane;
  glm::uint width, height;
  float fx, fy, cx, cy;
  float occlusion_m;
};
static_assert(offsetof(LandmarkPush, count) == 0);
static_assert(offsetof(LandmarkPush, near_plane) == 4);
static_assert(offsetof(LandmarkPush, width) == 8);
static_assert(offsetof(LandmarkPush, height) == 12);
static_assert(offsetof(LandmarkPush, fx) == 16);
static_assert(offsetof(LandmarkPush, fy) == 20);
static_assert(offsetof(LandmarkPush, cx) == 24);
static_assert(offsetof(LandmarkPush, cy) == 28);
static_assert(offsetof(LandmarkPush, occlusion_m) == 32);
static_assert(sizeof(LandmarkPush) == 36);

// tracker_input.comp, push constant block Push.
struct InputPush {
  glm::uint width, height, gradient;
  float fx, fy, cx, cy;
  float max_depth_jump;
};
static_assert(offsetof(InputPush, width) == 0);
static_assert(offsetof(InputPush, height) == 4);
static_assert(offsetof(InputPush, gradient) == 8);
static_assert(offsetof(InputPush, fx) == 12);
static_assert(offsetof(InputPush, fy) == 16);
static_assert(offsetof(InputPush, cx) == 20);
static_assert(offsetof(InputPush, cy) == 24);
static_assert(offsetof(InputPush, max_depth_jump) == 28);
static_assert(sizeof(InputPush) == 32);

// tracker_pyramid.comp, push constant block Push.
struct PyramidPush {
  glm::uint fine_width, fine_height, width, height;
  float depth_edge_threshold;
};
static_assert(offsetof(PyramidPush, fine_width) == 0);
static_assert(offsetof(PyramidPush, fine_height) == 4);
static_assert(offsetof(PyramidPush, width) == 8);
static_assert(offsetof(PyramidPush, height) == 12);
static_assert(offsetof(PyramidPush, depth_edge_threshold) == 16);
static_assert(sizeof(PyramidPush) == 20);

// tracker_vertices.comp, push constant block Push.
struct VerticesPush {
  glm::uint x_slot;  // first slot; workgroup row y handles slot x_slot + y
  glm::uint mode;    // 0 full sums, 1 fill identity_cache from the base, 2 identity_cache + expression
};
static_assert(offsetof(VerticesPush, x_slot) == 0);
static_assert(offsetof(VerticesPush, mode) == 4);
static_assert(sizeof(VerticesPush) == 8);

// tracker_evaluate.comp, push constant block Push.
struct EvaluatePush {
  glm::uint x_slot;          // first x in XVectors; workgroup row y evaluates x slot x_slot + y
  glm::uint write_jacobian;  // 0 residuals only, 1 J column-major, 2 J column- and row-major
};
static_assert(offsetof(EvaluatePush, x_slot) == 0);
static_assert(offsetof(EvaluatePush, write_jacobian) == 4);
static_assert(sizeof(EvaluatePush) == 8);

// tracker_jt.comp, push constant block Push.
struct JtPush {
  glm::uint rows, n, mode, p_offset, done_index, col_stride;
};
static_assert(offsetof(JtPush, rows) == 0);
static_assert(offsetof(JtPush, n) == 4);
static_assert(offsetof(JtPush, mode) == 8);
static_assert(offsetof(JtPush, p_offset) == 12);
static_assert(offsetof(JtPush, done_index) == 16);
static_assert(offsetof(JtPush, col_stride) == 20);
static_assert(sizeof(JtPush) == 24);

// tracker_reduce.comp, push constant block Push.
struct ReducePush {
  glm::uint count, groups;
};
static_assert(offsetof(ReducePush, count) == 0);
static_assert(offsetof(ReducePush, groups) == 4);
static_assert(sizeof(ReducePush) == 8);

// tracker_jtj.comp, push constant block Push.
struct JtjPush {
  glm::uint rows, n, rows_per_chunk, col_stride;  // rows_per_chunk: a multiple of 4
};
static_assert(offsetof(JtjPush, rows) == 0);
static_assert(offsetof(JtjPush, n) == 4);
static_assert(offsetof(JtjPush, rows_per_chunk) == 8);
static_assert(offsetof(JtjPush, col_stride) == 12);
static_assert(sizeof(JtjPush) == 16);

// tracker_pcg.comp, push constant block Push.
struct PcgPush {
  glm::uint stage, n, max_iterations, num_trials;
  glm::uint o_exp, k_exp, clamp_expression, groups;  // groups: partials to sum in stages 0 and 2
  float tolerance, damping;
};
static_assert(offsetof(PcgPush, stage) == 0);
static_assert(offsetof(PcgPush, n) == 4);
static_assert(offsetof(PcgPush, max_iterations) == 8);
static_assert(offsetof(PcgPush, num_trials) == 12);
static_assert(offsetof(PcgPush, o_exp) == 16);
static_assert(offsetof(PcgPush, k_exp) == 20);
static_assert(offsetof(PcgPush, clamp_expression) == 24);
static_assert(offsetof(PcgPush, groups) == 28);
static_assert(offsetof(PcgPush, tolerance) == 32);
static_assert(offsetof(PcgPush, damping) == 36);
static_assert(sizeof(PcgPush) == 40);

// tracker_loop.comp, push constant block Push.
struct LoopPush {
  glm::uint stage, level_index, block, iterations;
  glm::uint level, first_level, num_trials, identity_every_block;
  glm::uint vertex_groups, shade_groups, draw_vertices, classify_groups;
  glm::uint num_regularizer, capacity_rows, assembled, previous_cut;
  float w_point, w_plane, w_col, w_lan;
  float inverse_unit, landmark_scale, function_tolerance;
  glm::uint tracker_vertex_groups;  // tracker_vertices.comp's groups (the renderer's are render_*)
};
static_assert(offsetof(LoopPush, stage) == 0);
static_assert(offsetof(LoopPush, level_index) == 4);
static_assert(offsetof(LoopPush, block) == 8);
static_assert(offsetof(LoopPush, iterations) == 12);
static_assert(offsetof(LoopPush, level) == 16);
static_assert(offsetof(LoopPush, first_level) == 20);
static_assert(offsetof(LoopPush, num_trials) == 24);
static_assert(offsetof(LoopPush, identity_every_block) == 28);
static_assert(offsetof(LoopPush, vertex_groups) == 32);
static_assert(offsetof(LoopPush, shade_groups) == 36);
static_assert(offsetof(LoopPush, draw_vertices) == 40);
static_assert(offsetof(LoopPush, classify_groups) == 44);
static_assert(offsetof(LoopPush, num_regularizer) == 48);
static_assert(offsetof(LoopPush, capacity_rows) == 52);
static_assert(offsetof(LoopPush, assembled) == 56);
static_assert(offsetof(LoopPush, previous_cut) == 60);
static_assert(offsetof(LoopPush, w_point) == 64);
static_assert(offsetof(LoopPush, w_plane) == 68);
static_assert(offsetof(LoopPush, w_col) == 72);
static_assert(offsetof(LoopPush, w_lan) == 76);
static_assert(offsetof(LoopPush, inverse_unit) == 80);
static_assert(offsetof(LoopPush, landmark_scale) == 84);
static_assert(offsetof(LoopPush, function_tolerance) == 88);
static_assert(offsetof(LoopPush, tracker_vertex_groups) == 92);
static_assert(sizeof(LoopPush) == 96);

// tracker_loop.comp's state (floats), its indices.
enum LoopIndex : uint32_t {
  kLoopRunning = 0,
  kLoopSuspended = 3,  // a level still going where its recorded blocks ended: its index + 1
  kLoopTermination = 4,
  kLoopTermLevel = 5,
  kLoopTermIteration = 6,
  kLoopAccepted = 7,
  kLoopAttempted = 8,
  kLoopRecords = 9,
  kLoopOpenRecord = 10,
  kLoopOverflowRows = 11,
  kLoopInitial = 12,
  kLoopFinal = 17,
  kLoopConvergedAt = 24,  // one per scheduled level, at most kMaxDeviceLoopLevels
  kLoopHeader = 32,       // floats the host initialises
  kLoopRecordBase = 288,  // after x before the last step (kMaxUnknowns + 1 floats)
  kLoopRecordFloats = 18,
};
constexpr size_t kMaxDeviceLoopLevels = 8;
// Frames whose block counts predict how many blocks of a level the next frame records.
constexpr size_t kLoopHistoryFrames = 8;
// tracker_loop.comp's terminations.
enum class DeviceTermination { kDone = 0, kNoDataAtStart = 1, kStepLostFace = 2, kNonFinite = 3, kOverflow = 4 };
// tracker_loop.comp's indirect argument slots, 16 bytes each (a VkDispatchIndirectCommand, or for
// kArgDraw a VkDrawIndirectCommand).
enum ArgSlot : int {
  kArgIdentity = 0,
  kArgModel,
  kArgShade,
  kArgDraw,
  kArgClassify,
  kArgLandmarks,
  kArgVertices,
  kArgEvaluateJ,
  kArgEvaluateEnergy,
  kArgJt,
  kArgPcg,
  kArgTrialVertices,
  kArgTrialEvaluate,
  kArgJtj,
  kArgReduce,
  kArgCount,
  kDirect = -1,  // sizes from the host
};
static_assert(sizeof(VkDispatchIndirectCommand) <= 16 && sizeof(VkDrawIndirectCommand) == 16);
// tracker_common.glsl: a push-constant size the pass reads from its level's TrackParams.
constexpr uint32_t kSizeFromParams = 0xffffffffu;
// J's rows the device-driven loop allocates at first (grown when a frame needs more): the whole
// of the paper's level 1 of a 640x480 frame fits (8 rows per pixel, 85 columns: 209 MB).
constexpr uint64_t kDeviceLoopJacobianBudget = 256ull << 20;

// tracker_landmarks.comp, element of the Candidates buffer (vec4 candidates[]): the vertex index's
// bits (floatBitsToUint), u, v, confidence.
using LandmarkCandidate = glm::vec4;

constexpr uint32_t kRowsPerPixel = 8;     // tracker_common.glsl
// Per pixel of a level's input: point, normal, colour, colour gradient along u and along v
// (tracker_common.glsl: kInputVec4sPerPixel elements of the vec4 Input buffer).
constexpr size_t kInputVec4sPerPixel = 5;
constexpr uint32_t kPixelItemWords = 9;
constexpr uint32_t kEvaluateGroup = 64;   // tracker_evaluate.comp local size
constexpr uint32_t kJtChunk = 256;        // tracker_jt.comp rows per workgroup
constexpr uint32_t kJtjRowsPerChunk = 1024;
// tracker_jtj.comp's tiles of [J | r]'s columns and pairs of tiles per workgroup (tracker_common.glsl).
constexpr uint32_t kJtjTile = 8;
constexpr uint32_t kJtjPairsPerGroup = 64;
constexpr uint32_t jtj_pair_groups(uint32_t n) {
  const uint32_t tiles = (n + kJtjTile) / kJtjTile;
  return (tiles * (tiles + 1) / 2 + kJtjPairsPerGroup - 1) / kJtjPairsPerGroup;
}
constexpr uint32_t kMaxUnknowns = 255;    // tracker_common.glsl kMaxUnknowns
constexpr uint32_t kStateX = 16;          // tracker_pcg.comp: first vector of the state
constexpr uint32_t kStateFloats = kStateX + 6 * (kMaxUnknowns + 1);

constexpr VkBufferUsageFlags kStorage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;

// Indices into the PCG state (tracker_pcg.comp).
enum StateScalar { kRz = 0, kBNorm, kDone, kIterations, kInitialNorm, kFinalNorm, kConverged };

// What the linearisation pass found (read back to size J and set the pre-scales).
struct Counts {
  uint32_t pixels = 0, num_point = 0, num_plane = 0, num_color = 0, landmarks = 0, regularizer = 0;
  double landmark_weight = 0;
  uint32_t items() const { return pixels + landmarks + regularizer; }
  // Rows of the device's J (zero rows included).
  uint64_t rows() const { return uint64_t{kRowsPerPixel} * pixels + 2ull * landmarks + regularizer; }
  // Rows that carry a term, as the CPU counts them.
  Eigen::Index residuals() const {
    return 3 * Eigen::Index(num_point) + 2 * Eigen::Index(num_plane) + 3 * Eigen::Index(num_color) +
           2 * Eigen::Index(landmarks) + Eigen::Index(regularizer);
  }
  bool has_data() const { return pixels > 0 || landmarks > 0; }
};

struct Analysis {
  TermEnergies energy;               // at x (the linearisation point)
  std::vector<TermEnergies> trials;  // at clamp(x + 2^-h dx)
  Eigen::VectorXd dx;
  PcgSummary pcg;
  double wall_ms = 0;
};

// One pyramid level of the input: its colour and depth per pixel, uploaded (a level the host
// built, or level 0) or made on the device from the next finer level (tracker_pyramid.comp), and
// what the per-pixel passes read, which tracker_input.comp makes from them. Both passes are
// recorded into the first submission that linearises the level (record_linearization).
struct LevelInput {
  const InputFrame* frame = nullptr;  // its camera and landmarks; its pixels only when uploaded
  gpu::Buffer raw;   // uploaded: per pixel linear colour, depth (0 where InputFrame::depth_valid is false)
  gpu::Buffer made;  // the same made on the device from `made_from` (tracker_pyramid.comp)
  const gpu::Buffer* pixels = nullptr;  // `raw` or `made`: this frame's
  LevelInput* made_from = nullptr;      // the next finer level, while `made` is still to be made
  float depth_edge_threshold = 0;       // PyramidOptions::depth_edge_threshold, for making it
  gpu::Buffer data;        // per pixel: point (w = valid depth), normal (w = exists), colour, its gradient
  bool data_pending = false;  // `pixels` is newer than `data`
  bool has_depth = false;     // the frame has depth (InputFrame::has_depth)
  bool gradient = false;      // the colour gradient is made (ColorFollowsProjection)
  gpu::Buffer candidates;  // landmark candidates: vertex bits, u, v, confidence
  uint32_t num_candidates = 0;
};

}  // namespace

namespace {
// The device submissions a solve makes (each one a host wait) and the wall time inside them, for
// its summary (bench track's columns).
struct SubmissionMeter {
  explicit SubmissionMeter(const gpu::Context& c)
      : context(c), count(c.submissions()), ms(c.submission_ms()), recording_ms(c.recording_ms()) {}
  void Fill(SolverSummary* s) const {
    s->device_submissions = static_cast<int>(context.submissions() - count);
    s->device_submission_ms = context.submission_ms() - ms;
    s->device_recording_ms = context.recording_ms() - recording_ms;
  }
  const gpu::Context& context;
  const uint64_t count;
  const double ms, recording_ms;
};
}  // namespace

const char* vulkan_strategy_name(VulkanStrategy s) {
  switch (s) {
    case VulkanStrategy::kAuto: return "auto";
    case VulkanStrategy::kMatrixFree: return "matrix-free";
    case VulkanStrategy::kAssembled: return "assembled";
    case VulkanStrategy::kFromSolverOptions: return "from solver options";
  }
  return "?";
}

bool VulkanSolverOptions::IsValid(std::string* why) const {
  switch (strategy) {
    case VulkanStrategy::kAuto:
    case VulkanStrategy::kMatrixFree:
    case VulkanStrategy::kAssembled:
    case VulkanStrategy::kFromSolverOptions:
      return true;
  }
  if (why) *why = "Vulkan solver: unknown strategy";
  return false;
}

struct VulkanSolver::Impl {
  Impl(const gpu::Context& c, TrackerModel m, const VulkanSolverOptions& o)
      : context(c), model(std::move(m)), options(o), renderer(c, model.render, gpu::Renderer::Options{false}) {}

  const gpu::Context& context;
  TrackerModel model;
  VulkanSolverOptions options;
  VulkanStrategyChoice choice;
  gpu::Renderer renderer;

  std::unique_ptr<gpu::ComputePipeline> downsample, input, classify, landmarks, vertices_pass, evaluate, jt, reduce, jtj, pcg, loop;
  gpu::Buffer mean_shape, identity_basis, expression_basis, mean_albedo, albedo_basis;  // row-major
  gpu::Buffer vertex_parts;  // per vertex its FacePart, one uint each (classify: EnergyOptions::color_parts)
  gpu::Buffer identity_columns, expression_columns, albedo_columns;  // column-major (tracker_vertices.comp)
  gpu::Buffer vertices;  // per x slot: position, albedo per vertex
  gpu::Buffer identity_cache;  // a_id + E_id alpha | albedo of the base (tracking: identity fixed)
  bool cache_identity = false;  // the current layout solves neither identity nor albedo
  gpu::Buffer g_position, g_normal, g_bary, g_ids, g_color, items, landmark_items, counters, counters_readback;
  gpu::Buffer params, base, xs, residuals, jacobian, jacobian_columns, energy_partials, jt_partials, reduced, product;
  gpu::Buffer jtj_partials, jtj_reduced, state, readback;
  // FR_TRACKER_PROFILE=1: GPU time per analysis stage on stderr (timestamp queries).
  std::unique_ptr<gpu::TimestampQueries> profile;
  // The device-driven loop (solve_device_loop): its state and records, the indirect arguments
  // tracker_loop.comp writes, one TrackParams per scheduled level (the host writes what it
  // knows ahead, the device the counts and scales), J's rows (0: not sized yet), and the
  // timestamps that split its one submission into synthesis and analysis per iteration.
  gpu::Buffer loop_state, loop_args;
  std::vector<gpu::Buffer> level_params;
  uint64_t loop_capacity_rows = 0;
  std::unique_ptr<gpu::TimestampQueries> loop_timestamps;
  // Per schedule (its levels and iterations: the tracker's per-frame and recovery schedules
  // differ) and per scheduled level, the blocks the last frames used (at most
  // kLoopHistoryFrames): a frame records as many as the most of them, not the iterations a
  // converged level skips.
  std::map<std::vector<int>, std::vector<std::deque<uint32_t>>> loop_history;
  // Where the recorded passes take their sizes: the host's counts and `params` (host-driven), or
  // tracker_loop.comp's arguments and the level's TrackParams (device-driven: `device_params` set).
  const gpu::Buffer* device_params = nullptr;

  // The linearisation the buffers currently hold.
  Counts counts;
  ParameterLayout layout;
  uint32_t n = 0;

  void ensure(gpu::Buffer& b, VkDeviceSize bytes, gpu::BufferDomain domain, const char* name) {
    bytes = std::max<VkDeviceSize>(bytes, 16);
    if (b.valid() && b.size() >= bytes) return;
    const VkDeviceSize limit = context.properties().limits.maxStorageBufferRange;
    if (bytes > limit) {
      throw Error(std::string("Vulkan solver: the ") + name + " needs " + std::to_string(bytes) +
                  " bytes, more than the device's storage buffer range of " + std::to_string(limit) +
                  " (track on a coarser pyramid level or a smaller input)");
    }
    b = gpu::Buffer();  // free first: the old one may be large
    b = gpu::Buffer(context, std::min<VkDeviceSize>(limit, bytes + bytes / 4), kStorage, domain, name);
  }

  // The G-buffer copies the per-pixel pass reads and its compacted items, for `pixels` pixels.
  void ensure_pixel_buffers(VkDeviceSize pixels) {
    const VkDeviceSize plane = pixels * 16;  // one vec4 per pixel
    ensure(g_position, plane, gpu::BufferDomain::Device, "tracker G-buffer positions");
    ensure(g_normal, plane, gpu::BufferDomain::Device, "tracker G-buffer normals");
    ensure(g_bary, plane, gpu::BufferDomain::Device, "tracker G-buffer barycentrics");
    ensure(g_ids, plane, gpu::BufferDomain::Device, "tracker G-buffer ids");
    ensure(g_color, plane, gpu::BufferDomain::Device, "tracker G-buffer colours");
    ensure(items, pixels * kPixelItemWords * 4, gpu::BufferDomain::Device, "tracker pixel items");
  }

  void init() {
    std::string why;
    if (!options.IsValid(&why)) throw Error(why);
    if (!model.IsValid(&why)) throw Error("Vulkan solver: " + why);
    if (model.num_identity() + model.num_albedo() + model.num_expression() > 512) {
      throw Error("Vulkan solver: the model has more than 512 coefficients (tracker_evaluate.comp stages them in shared memory)");
    }
    auto upload = [&](gpu::Buffer& b, const float* data, size_t count, const char* name) {
      b = gpu::Buffer(context, std::max<size_t>(count * sizeof(float), 16), kStorage, gpu::BufferDomain::Device, name);
      if (count) b.write(data, count * sizeof(float));
    };
    const auto& r = model.render;
    const Eigen::MatrixXf id_columns = r.identity_basis, ex_columns = r.expression_basis, al_columns = r.albedo_basis;
    upload(mean_shape, r.mean_shape.data(), r.mean_shape.size(), "tracker mean shape");
    upload(identity_basis, r.identity_basis.data(), r.identity_basis.size(), "tracker identity basis (row-major)");
    upload(expression_basis, r.expression_basis.data(), r.expression_basis.size(), "tracker expression basis (row-major)");
    upload(mean_albedo, r.mean_albedo.data(), r.mean_albedo.size(), "tracker mean albedo");
    upload(albedo_basis, r.albedo_basis.data(), r.albedo_basis.size(), "tracker albedo basis (row-major)");
    upload(identity_columns, id_columns.data(), id_columns.size(), "tracker identity basis (column-major)");
    upload(expression_columns, ex_columns.data(), ex_columns.size(), "tracker expression basis (column-major)");
    upload(albedo_columns, al_columns.data(), al_columns.size(), "tracker albedo basis (column-major)");
    const std::vector<uint32_t> parts(r.vertex_part.begin(), r.vertex_part.end());
    vertex_parts = gpu::Buffer(context, std::max<size_t>(parts.size() * 4, 16), kStorage, gpu::BufferDomain::Device,
                               "tracker vertex parts");
    if (!parts.empty()) vertex_parts.write(parts.data(), parts.size() * 4);
    namespace sh = gpu::shaders;
    downsample = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_pyramid_comp, 2, sizeof(PyramidPush),
                                                         "tracker input pyramid");
    input = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_input_comp, 2, sizeof(InputPush),
                                                    "tracker level input");
    classify = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_classify_comp, 9, sizeof(ClassifyPush),
                                                       "tracker linearisation");
    landmarks = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_landmarks_comp, 5, sizeof(LandmarkPush),
                                                        "tracker landmark pruning");
    vertices_pass = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_vertices_comp, 10, sizeof(VerticesPush),
                                                            "tracker vertex positions + albedo");
    evaluate = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_evaluate_comp, 16, sizeof(EvaluatePush),
                                                       "tracker residuals + Jacobian");
    jt = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_jt_comp, 6, sizeof(JtPush), "tracker J^T products");
    reduce = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_reduce_comp, 3, sizeof(ReducePush),
                                                     "tracker reduction");
    jtj = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_jtj_comp, 4, sizeof(JtjPush),
                                                  "tracker J^T J assembly");
    pcg = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_pcg_comp, 4, sizeof(PcgPush), "tracker PCG");
    loop = std::make_unique<gpu::ComputePipeline>(context, sh::tracker_loop_comp, 10, sizeof(LoopPush),
                                                   "tracker Gauss-Newton loop control");
    loop_args = gpu::Buffer(context, kArgCount * 16, kStorage | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, gpu::BufferDomain::Device,
                            "tracker loop indirect arguments");
    if (context.timestamps_supported()) {
      loop_timestamps = std::make_unique<gpu::TimestampQueries>(context, 32, "tracker device-driven loop");
    }
    counters = gpu::Buffer(context, sizeof(Counters), kStorage, gpu::BufferDomain::Device, "tracker counters");
    counters_readback = gpu::Buffer(context, sizeof(Counters), kStorage, gpu::BufferDomain::Readback,
                                    "tracker counters readback");
    params = gpu::Buffer(context, sizeof(TrackParams), kStorage, gpu::BufferDomain::Upload, "tracker parameters");
    state = gpu::Buffer(context, kStateFloats * sizeof(float), kStorage, gpu::BufferDomain::Device, "tracker PCG state");
    if (const char* env = std::getenv("FR_TRACKER_PROFILE"); env && *env == '1' && context.timestamps_supported()) {
      profile = std::make_unique<gpu::TimestampQueries>(context, 6, "tracker analysis stages");
    }
    identity_cache = gpu::Buffer(context, std::max<size_t>(6 * static_cast<size_t>(model.num_vertices()) * 4, 16), kStorage,
                                 gpu::BufferDomain::Device, "tracker identity cache");
    landmark_items = gpu::Buffer(context, (std::max<size_t>(model.landmarks.size(), 1) + 68) * sizeof(glm::vec4), kStorage,
                                 gpu::BufferDomain::Device, "tracker landmark items");
  }

  // Fills `li` for frame `f`, a level the host built: its colour and depth per pixel written
  // straight into the upload buffer (tracker_input.comp makes the rest on the device), and the
  // landmark candidates. The buffers are kept from frame to frame and grow only when a level
  // gets larger: allocating them per frame cost a real GPU's driver more than the level's whole
  // analysis (bench track, 2026-11-24).
  void prepare_level(const InputFrame& f, const EnergyOptions& energy, int threads, LevelInput* out) {
    LevelInput& li = *out;
    li.frame = &f;
    upload_pixels(f, threads, &li);  // `f` is valid (checked by the caller)
    prepare_level_input(f, f.has_depth(), ColorFollowsProjection(energy, f), energy, &li);
  }

  // The solve's pyramid made on the device from `frame` (level 0, uploaded): `levels` are its
  // levels without pixels (PyramidLevelsWithoutPixels), each level down to the coarsest scheduled
  // one is made from the one above it before the first linearisation that reads it. Uploading the
  // 640x480 frame once costs the host less than building the levels (BuildPyramid) and uploading
  // them.
  void prepare_pyramid_on_device(const InputFrame& frame, const std::vector<InputFrame>& levels,
                                 const SolverOptions& o, std::unordered_map<int, LevelInput>& inputs) {
    int coarsest = 0;
    for (const LevelSchedule& s : o.schedule) coarsest = std::max(coarsest, s.level);
    LevelInput& top = inputs[0];
    top.frame = &levels[0];
    if (!upload_pixels(frame, o.threads, &top)) throw Error(kNonFiniteColorMessage);
    for (int l = 1; l <= coarsest; ++l) {
      LevelInput& li = inputs[l];
      const InputFrame& f = levels[static_cast<size_t>(l)];
      li.frame = &f;
      ensure(li.made, static_cast<VkDeviceSize>(f.width()) * f.height() * sizeof(glm::vec4), gpu::BufferDomain::Device,
             "tracker level colour and depth (made on the device)");
      li.pixels = &li.made;
      li.made_from = &inputs.at(l - 1);
      li.depth_edge_threshold = o.pyramid.depth_edge_threshold;
    }
    for (const LevelSchedule& s : o.schedule) {
      LevelInput& li = inputs.at(s.level);
      prepare_level_input(*li.frame, frame.has_depth(), ColorFollowsProjection(o.energy, frame), o.energy, &li);
    }
  }

  // `li.raw`: the colour and the depth of `f` (0 where not valid), rows split over `threads`.
  // False when a colour value is not finite (InputFrame::IsValid's check, made while the values
  // pass by: reading a 640x480 frame's colour once more cost a real GPU's host 0.4 ms).
  bool upload_pixels(const InputFrame& f, int threads, LevelInput* out) {
    LevelInput& li = *out;
    const int w = f.width(), h = f.height();
    ensure(li.raw, static_cast<size_t>(w) * h * sizeof(glm::vec4), gpu::BufferDomain::Upload,
           "tracker level colour and depth");
    li.pixels = &li.raw;
    li.made_from = nullptr;
    auto* raw = static_cast<glm::vec4*>(li.raw.mapped());
    constexpr int kRowsPerItem = 32;
    std::atomic<bool> finite{true};
    ParallelFor((h + kRowsPerItem - 1) / kRowsPerItem, ResolvedThreadCount(threads), [&](int item) {
      bool item_finite = true;
      for (int j = item * kRowsPerItem; j < std::min(h, (item + 1) * kRowsPerItem); ++j) {
        for (int i = 0; i < w; ++i) {
          const size_t p = static_cast<size_t>(j) * w + i;
          const float depth = f.depth_valid(i, j) ? f.depth[p] : 0.f;
          const glm::vec4 pixel(f.color[3 * p], f.color[3 * p + 1], f.color[3 * p + 2], depth);
          item_finite &= std::isfinite(pixel.x) && std::isfinite(pixel.y) && std::isfinite(pixel.z);
          raw[p] = pixel;  // whole pixels: the mapping may be write-combined
        }
      }
      if (!item_finite) finite = false;
    });
    return finite;
  }

  // The level's per-pixel input buffer (made by tracker_input.comp) and its landmark candidates
  // (from `f`'s landmarks; `f` may have no pixels).
  void prepare_level_input(const InputFrame& f, bool has_depth, bool gradient, const EnergyOptions& energy,
                           LevelInput* out) {
    LevelInput& li = *out;
    const size_t pixels = static_cast<size_t>(f.width()) * f.height();
    ensure(li.data, kInputVec4sPerPixel * pixels * sizeof(glm::vec4), gpu::BufferDomain::Device, "tracker level input");
    li.data_pending = true;
    li.has_depth = has_depth;
    li.gradient = gradient;
    // Landmark candidates exactly as Linearize filters them before visibility.
    std::unordered_map<int, int> vertex_of;
    for (const auto& l : model.landmarks) {
      if (!EnergyUsesLandmark(energy, l.ibug_index, l.flags, has_depth)) continue;
      vertex_of[l.ibug_index] = l.vertex;
    }
    std::vector<LandmarkCandidate> cand;
    if (energy.use_landmarks) {
      for (const auto& in : f.landmarks) {
        if (!(in.confidence > 0.f)) continue;
        auto it = vertex_of.find(in.ibug_index);
        if (it == vertex_of.end()) continue;
        const int bound = LandmarkVertex(in, it->second, model.num_vertices());
        if (bound < 0) continue;
        const float vertex_bits = std::bit_cast<float>(static_cast<glm::uint>(bound));
        cand.emplace_back(vertex_bits, in.position.x(), in.position.y(), in.confidence);
      }
    }
    li.num_candidates = static_cast<uint32_t>(cand.size());
    ensure(li.candidates, cand.size() * sizeof(LandmarkCandidate), gpu::BufferDomain::Upload,
           "tracker landmark candidates");
    if (!cand.empty()) li.candidates.write(cand.data(), cand.size() * sizeof(LandmarkCandidate));
  }

  // The level's colour and depth made on the device from the next finer level's, that one's
  // first when it is still to be made too: once per frame.
  void record_made_pixels(gpu::CommandRecorder& rec, LevelInput& li) {
    if (!li.made_from) return;
    LevelInput& fine = *li.made_from;
    record_made_pixels(rec, fine);
    const auto w = static_cast<glm::uint>(li.frame->width()), h = static_cast<glm::uint>(li.frame->height());
    rec.bind(*downsample);
    rec.set_storage_buffer(0, *fine.pixels);
    rec.set_storage_buffer(1, li.made);
    rec.push_constants(PyramidPush{static_cast<glm::uint>(fine.frame->width()),
                                   static_cast<glm::uint>(fine.frame->height()), w, h, li.depth_edge_threshold});
    rec.dispatch((w * h + 63) / 64, 1, 1);
    compute_barrier(rec);
    li.made_from = nullptr;
  }

  // After a render: its G-buffer copied into the buffers the per-pixel pass reads, the pass
  // (classification, compaction) and the landmark pruning, recorded into the render's
  // submission. Host-driven: the counters are zeroed first and copied for the host after;
  // device-driven (`device`): tracker_loop.comp zeroes and reads them, and sizes the two passes.
  void record_linearization(gpu::CommandRecorder& rec, const gpu::GBufferTargets& targets, LevelInput& li,
                            const EnergyOptions& e, bool device) {
    const InputFrame& f = *li.frame;
    const VkCommandBuffer cmd = rec.handle();
    const uint32_t w = static_cast<uint32_t>(f.width()), h = static_cast<uint32_t>(f.height());
    // This level's input from its colour and depth (made on the device first, where they are
    // made there): once per frame (per calibration frame).
    if (li.data_pending) {
      record_made_pixels(rec, li);
      rec.bind(*input);
      rec.set_storage_buffer(0, *li.pixels);
      rec.set_storage_buffer(1, li.data);
      rec.push_constants(InputPush{w, h, li.gradient ? 1u : 0u, f.camera.fx, f.camera.fy, f.camera.cx, f.camera.cy,
                                   static_cast<float>(e.max_depth_jump_m)});
      rec.dispatch((w * h + 63) / 64, 1, 1);
      compute_barrier(rec);
      li.data_pending = false;
    }
    const std::pair<const gpu::Image*, const gpu::Buffer*> copies[] = {
        {&targets.position, &g_position}, {&targets.normal, &g_normal}, {&targets.barycentric, &g_bary},
        {&targets.ids, &g_ids}, {&targets.color, &g_color}};
    constexpr uint32_t kCopies = 5;
    // GENERAL -> TRANSFER_SRC for the copies and back, so the renderer's bookkeeping
    // (Image::layout == GENERAL after render) stays true.
    auto transition = [&](VkImageLayout from, VkImageLayout to, VkPipelineStageFlags2 src_stage,
                          VkAccessFlags2 src_access, VkPipelineStageFlags2 dst_stage, VkAccessFlags2 dst_access) {
      VkImageMemoryBarrier2 barriers[kCopies];
      for (uint32_t k = 0; k < kCopies; ++k) {
        barriers[k] = {VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER_2};
        barriers[k].srcStageMask = src_stage;
        barriers[k].srcAccessMask = src_access;
        barriers[k].dstStageMask = dst_stage;
        barriers[k].dstAccessMask = dst_access;
        barriers[k].oldLayout = from;
        barriers[k].newLayout = to;
        barriers[k].srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
        barriers[k].dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
        barriers[k].image = copies[k].first->handle();
        barriers[k].subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
      }
      VkDependencyInfo dep{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
      dep.imageMemoryBarrierCount = kCopies;
      dep.pImageMemoryBarriers = barriers;
      vkCmdPipelineBarrier2(cmd, &dep);
    };
    transition(VK_IMAGE_LAYOUT_GENERAL, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
               VK_ACCESS_2_MEMORY_WRITE_BIT, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_READ_BIT);
    for (const auto& [image, buffer] : copies) {
      VkBufferImageCopy region{};
      region.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
      region.imageExtent = {w, h, 1};
      vkCmdCopyImageToBuffer(cmd, image->handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, buffer->handle(), 1, &region);
    }
    transition(VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_IMAGE_LAYOUT_GENERAL, VK_PIPELINE_STAGE_2_COPY_BIT,
               VK_ACCESS_2_NONE, VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_READ_BIT);
    if (!device) vkCmdFillBuffer(cmd, counters.handle(), 0, sizeof(Counters), 0);  // device-driven: tracker_loop.comp zeroes them
    rec.memory_barrier(VK_PIPELINE_STAGE_2_COPY_BIT | VK_PIPELINE_STAGE_2_CLEAR_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                       VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
    if (cache_identity && !device) record_vertices(rec, 0, 1, 1);  // device-driven: once per frame
    rec.bind(*classify);
    const gpu::Buffer* cb[] = {&g_position, &g_normal, &g_bary, &g_ids,   &li.data,
                               &items,      &counters, &g_color, &vertex_parts};
    for (uint32_t i = 0; i < 9; ++i) rec.set_storage_buffer(i, *cb[i]);
    const bool geometry = li.has_depth && (e.use_point || e.use_plane);
    rec.push_constants(ClassifyPush{w, h, li.has_depth ? 1u : 0u, geometry && e.use_point ? 1u : 0u,
                                    geometry && e.use_plane ? 1u : 0u, e.use_color ? 1u : 0u,
                                    static_cast<float>(e.max_point_distance_m), static_cast<float>(e.min_normal_dot),
                                    li.gradient ? static_cast<float>(e.color_robust_threshold) : 0.f,
                                    e.color_parts, static_cast<glm::uint>(e.pixel_sampling)});
    dispatch(rec, device ? kArgClassify : kDirect, (w * h + 63) / 64, 1);
    rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                       VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
    rec.bind(*landmarks);
    rec.set_storage_buffer(0, li.candidates);
    rec.set_storage_buffer(1, renderer.camera_positions());
    rec.set_storage_buffer(2, g_position);
    rec.set_storage_buffer(3, landmark_items);
    rec.set_storage_buffer(4, counters);
    rec.push_constants(LandmarkPush{li.num_candidates, f.camera.near_plane, w, h, f.camera.fx, f.camera.fy, f.camera.cx,
                                    f.camera.cy, static_cast<float>(e.landmark_occlusion_m)});
    dispatch(rec, device ? kArgLandmarks : kDirect, 1, 1);
    if (device) return;  // tracker_loop.comp reads the counters on the device
    rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_READ_BIT);
    VkBufferCopy copy{0, 0, sizeof(Counters)};
    vkCmdCopyBuffer(cmd, counters.handle(), counters_readback.handle(), 1, &copy);
    rec.memory_barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_2_HOST_BIT,
                       VK_ACCESS_2_HOST_READ_BIT);
  }

  // Renders `p` for the level and runs the linearisation pass; returns its counts.
  // `regularize_shared` false: a calibration frame after the first, whose identity/albedo prior
  // rows the first frame carries (energy.h, Linearization::regularize_shared).
  Counts linearize(LevelInput& li, const ParameterLayout& l, const gpu::FaceParameters& p, const SolverOptions& o,
                   double* synthesis_ms, double* analysis_ms, bool regularize_shared = true) {
    const InputFrame& f = *li.frame;
    const auto t0 = Clock::now();
    const uint32_t w = static_cast<uint32_t>(f.width()), h = static_cast<uint32_t>(f.height());
    ensure_pixel_buffers(VkDeviceSize{w} * h);
    const EnergyOptions& e = o.energy;
    // Model sizes and base coefficients now (the identity cache pass reads them); the counts
    // and scales follow once the linearisation has run.
    cache_identity = l.num_identity == 0 && l.num_albedo == 0;
    write_params(Counts{}, l, p, e, f.camera, regularize_shared);
    ensure(xs, static_cast<VkDeviceSize>(l.num_parameters()) * 4, gpu::BufferDomain::Upload, "tracker parameter vectors");
    ensure(vertices, static_cast<VkDeviceSize>(model.num_vertices()) * 24, gpu::BufferDomain::Device, "tracker vertices");
    // The render and the linearisation of its G-buffer in one submission: one host wait fewer
    // per Gauss-Newton iteration (on a real GPU the waits, not the work, set the pace).
    renderer.render(p, f.camera, o.render, [&](VkCommandBuffer cmd, const gpu::GBufferTargets& targets) {
      gpu::CommandRecorder rec(context, cmd);
      record_after_everything_before(rec);
      record_linearization(rec, targets, li, e, false);
    });
    // The submission's time is the synthesis row's: the render and the pass that classifies its pixels.
    *synthesis_ms += ms_since(t0);
    const auto t1 = Clock::now();
    Counters c{};
    counters_readback.read(&c, sizeof(c));
    Counts out;
    out.pixels = c.pixel_count;
    out.num_point = c.num_point;
    out.num_plane = c.num_plane;
    out.num_color = c.num_color;
    out.landmarks = c.landmark_count;
    out.landmark_weight = c.landmark_weight;
    out.regularizer = e.use_regularizer ? static_cast<uint32_t>(RegularizerRows(l, regularize_shared)) : 0;
    write_params(out, l, p, e, f.camera, regularize_shared);
    *analysis_ms += ms_since(t1);
    return out;
  }

  // The TrackParams of a linearisation into `target` (default: `params`) and the base
  // coefficients into `base`.
  void write_params(const Counts& c, const ParameterLayout& l, const gpu::FaceParameters& p, const EnergyOptions& e,
                    const gpu::PinholeCamera& cam, bool regularize_shared, gpu::Buffer* target = nullptr) {
    counts = c;
    layout = l;
    n = static_cast<uint32_t>(l.num_parameters());
    TrackParams t{};
    t.num_pixels = c.pixels;
    t.num_landmarks = c.landmarks;
    t.num_regularizer = c.regularizer;
    t.n = n;
    t.k_id = l.num_identity;
    t.k_alb = l.num_albedo;
    t.k_exp = l.num_expression;
    t.o_id = l.offset(Block::kIdentity);
    t.o_alb = l.offset(Block::kAlbedo);
    t.o_exp = l.offset(Block::kExpression);
    t.o_gam = l.offset(Block::kLighting);
    t.o_rot = l.offset(Block::kRotation);
    t.o_t = l.offset(Block::kTranslation);
    t.model_id = model.num_identity();
    t.model_alb = model.num_albedo();
    t.model_exp = model.num_expression();
    t.num_vertices = model.num_vertices();
    t.width = cam.width;
    t.regularize_shared = regularize_shared ? 1u : 0u;
    t.rows = static_cast<uint32_t>((c.rows() + 3) / 4 * 4);  // column stride of the column-major J
    const double unit = e.geometry_unit_m;
    t.s_point = c.num_point ? static_cast<float>(std::sqrt(e.w_point / c.num_point) / unit) : 0.f;
    t.s_plane = c.num_plane ? static_cast<float>(std::sqrt(e.w_plane / c.num_plane) / unit) : 0.f;
    t.s_col = c.num_color ? static_cast<float>(std::sqrt(e.w_col / c.num_color)) : 0.f;
    t.s_lan = c.landmarks && c.landmark_weight > 0
                  ? static_cast<float>(std::sqrt(e.w_lan / c.landmark_weight) * e.landmark_reference_width / cam.width)
                  : 0.f;
    t.s_reg = static_cast<float>(std::sqrt(e.w_reg));
    t.fx = cam.fx;
    t.fy = cam.fy;
    t.cx = cam.cx;
    t.cy = cam.cy;
    t.s_reg_exp = static_cast<float>(std::sqrt(e.w_reg_expression)) / model.expression_sigma;
    t.w_sparse_exp = static_cast<float>(e.w_expression_sparsity);
    t.sparse_eps_exp = static_cast<float>(e.expression_sparsity_epsilon);
    const Eigen::Matrix3f r0 = gpu::rotation_from_euler(p.euler);
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) t.r0[3 * i + j] = r0(i, j);
    }
    (target ? *target : params).write(&t, sizeof(t));
    // alpha | beta | delta (the base, zero-padded) | 1/sigma_id | 1/sigma_alb
    const int kid = model.num_identity(), kalb = model.num_albedo(), kexp = model.num_expression();
    std::vector<float> b(static_cast<size_t>(2 * kid + 2 * kalb + kexp) + 1, 0.f);
    auto pad = [&](const Eigen::VectorXf& v, int count, size_t at) {
      for (int q = 0; q < count && q < v.size(); ++q) b[at + q] = v[q];
    };
    pad(p.alpha, kid, 0);
    pad(p.beta, kalb, kid);
    pad(p.delta, kexp, kid + kalb);
    for (int q = 0; q < kid; ++q) b[kid + kalb + kexp + q] = 1.f / model.identity_sigma[q];
    for (int q = 0; q < kalb; ++q) b[2 * kid + kalb + kexp + q] = 1.f / model.albedo_sigma[q];
    ensure(base, b.size() * sizeof(float), gpu::BufferDomain::Upload, "tracker base coefficients");
    base.write(b.data(), b.size() * sizeof(float));
  }

  uint32_t evaluate_groups() const { return (counts.items() + kEvaluateGroup - 1) / kEvaluateGroup; }

  const gpu::Buffer& track_params() const { return device_params ? *device_params : params; }

  // A pass's dispatch: groups from the host, or from tracker_loop.comp's arguments (`arg`).
  void dispatch(gpu::CommandRecorder& rec, int arg, uint32_t x, uint32_t y) const {
    if (arg == kDirect) {
      rec.dispatch(x, y, 1);
    } else {
      rec.dispatch_indirect(loop_args, VkDeviceSize{16} * static_cast<uint32_t>(arg));
    }
  }

  void compute_barrier(gpu::CommandRecorder& rec) const {
    rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                       VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
  }

  // tracker_vertices.comp's workgroups: one invocation per coordinate row, 64 per group.
  uint32_t vertex_groups() const { return (3 * static_cast<uint32_t>(model.num_vertices()) + 63) / 64; }

  void record_vertices(gpu::CommandRecorder& rec, uint32_t first, uint32_t mode, uint32_t count, int arg = kDirect) const {
    rec.bind(*vertices_pass);
    const gpu::Buffer* vb[] = {&track_params(), &xs,         &base,          &mean_shape,    &identity_columns,
                               &expression_columns, &mean_albedo, &albedo_columns, &vertices, &identity_cache};
    for (uint32_t i = 0; i < 10; ++i) rec.set_storage_buffer(i, *vb[i]);
    rec.push_constants(VerticesPush{first, mode});
    dispatch(rec, arg, vertex_groups(), count);
  }

  // Vertex positions/albedos of x slots [first, first + count), then their residuals (and J,
  // only for a single slot) - two dispatches whatever the count: on lavapipe every dispatch and
  // barrier is a synchronisation of the worker threads, costly on a loaded machine.
  // write_jacobian: 0 residuals only, 1 J column-major (the solve), 2 also row-major (Inspect).
  void record_evaluate(gpu::CommandRecorder& rec, uint32_t first, uint32_t write_jacobian, uint32_t count = 1) const {
    record_vertices(rec, first, cache_identity ? 2u : 0u, count);
    compute_barrier(rec);
    if (evaluate_groups() == 0) return;
    record_evaluate_pass(rec, first, write_jacobian, count, kDirect);
  }

  // The residual (and J) pass alone, for x slots [first, first + count) whose vertices are there.
  void record_evaluate_pass(gpu::CommandRecorder& rec, uint32_t first, uint32_t write_jacobian, uint32_t count,
                            int arg) const {
    rec.bind(*evaluate);
    const gpu::Buffer* b[] = {&track_params(), &xs,           &base,    &vertices,       &identity_basis,
                              &expression_basis, &mean_albedo, &albedo_basis, &items,  &landmark_items,
                              nullptr,       &renderer.camera_normals(), &residuals, &jacobian, &energy_partials};
    for (uint32_t i = 0; i < 15; ++i) {
      if (b[i]) rec.set_storage_buffer(i, *b[i]);
    }
    rec.set_storage_buffer(10, *current_input);
    rec.set_storage_buffer(15, jacobian_columns);
    rec.push_constants(EvaluatePush{first, write_jacobian});
    dispatch(rec, arg, evaluate_groups(), count);
  }

  // [J^T J | J^T r]: n rows of n + 1 (tracker_jtj.comp).
  uint32_t entry_count() const { return n * (n + 1); }
  // Column stride of the column-major J: rows rounded up to 4 (tracker_jt.comp reads vec4s).
  uint32_t column_stride() const { return static_cast<uint32_t>((counts.rows() + 3) / 4 * 4); }
  uint32_t jt_chunks() const { return static_cast<uint32_t>((counts.rows() + kJtChunk - 1) / kJtChunk); }
  uint32_t jtj_chunks() const { return static_cast<uint32_t>((counts.rows() + kJtjRowsPerChunk - 1) / kJtjRowsPerChunk); }

  void ensure_system_buffers(bool jacobian_needed, uint32_t slots, bool row_major_needed = false) {
    const uint64_t m = counts.rows();
    ensure(residuals, m * 4, gpu::BufferDomain::Device, "tracker residuals");
    ensure(jacobian, row_major_needed ? m * n * 4 : 16, gpu::BufferDomain::Device, "tracker Jacobian (row-major)");
    ensure(jacobian_columns, jacobian_needed ? uint64_t{column_stride()} * n * 4 : 16, gpu::BufferDomain::Device, "tracker Jacobian (column-major)");
    ensure(energy_partials, VkDeviceSize{slots} * std::max(evaluate_groups(), 1u) * 5 * 4, gpu::BufferDomain::Device,
           "tracker energy partials");
    ensure(xs, VkDeviceSize{slots} * n * 4, gpu::BufferDomain::Upload, "tracker parameter vectors");
    ensure(vertices, VkDeviceSize{slots} * model.num_vertices() * 24, gpu::BufferDomain::Device, "tracker vertices");
    ensure(jt_partials, VkDeviceSize{std::max(jt_chunks(), 1u)} * 2 * n * 4, gpu::BufferDomain::Device,
           "tracker J^T partials");
    ensure(reduced, VkDeviceSize{2} * n * 4, gpu::BufferDomain::Device, "tracker J^T r | diag");
    ensure(product, VkDeviceSize{n} * 4, gpu::BufferDomain::Device, "tracker J^T J p");
  }

  // `groups`: the partials to sum (kSizeFromParams: tracker_jtj.comp's chunks of the level's rows).
  void record_reduce(gpu::CommandRecorder& rec, const gpu::Buffer& partials, const gpu::Buffer& out, uint32_t count,
                     uint32_t groups, int arg = kDirect) const {
    if (count == 0) return;
    rec.bind(*reduce);
    rec.set_storage_buffer(0, partials);
    rec.set_storage_buffer(1, out);
    rec.set_storage_buffer(2, track_params());
    rec.push_constants(ReducePush{count, groups});
    dispatch(rec, arg, (count + 63) / 64, 1);
  }

  // Device-driven (`arg` given): the rows and J's column stride come from the level's TrackParams.
  void record_jt(gpu::CommandRecorder& rec, uint32_t mode, int arg = kDirect) const {
    rec.bind(*jt);
    rec.set_storage_buffer(0, jacobian);
    rec.set_storage_buffer(1, residuals);
    rec.set_storage_buffer(2, state);
    rec.set_storage_buffer(3, jt_partials);
    rec.set_storage_buffer(4, jacobian_columns);
    rec.set_storage_buffer(5, track_params());
    const bool device = arg != kDirect;
    rec.push_constants(JtPush{device ? kSizeFromParams : static_cast<uint32_t>(counts.rows()), n, mode, kStateX + 3 * n,
                              kDone, device ? kSizeFromParams : column_stride()});
    dispatch(rec, arg, jt_chunks(), 1);
  }

  void record_jtj(gpu::CommandRecorder& rec, int arg = kDirect) const {
    rec.bind(*jtj);
    rec.set_storage_buffer(0, jacobian_columns);
    rec.set_storage_buffer(1, residuals);
    rec.set_storage_buffer(2, jtj_partials);
    rec.set_storage_buffer(3, track_params());
    const bool device = arg != kDirect;
    rec.push_constants(JtjPush{device ? kSizeFromParams : static_cast<uint32_t>(counts.rows()), n, kJtjRowsPerChunk,
                               device ? kSizeFromParams : column_stride()});
    dispatch(rec, arg, jtj_chunks(), jtj_pair_groups(n));
  }

  // `groups`: jt partials to sum in stages 0 and 2 (kSizeFromParams: the chunks of the level's rows).
  void record_pcg(gpu::CommandRecorder& rec, uint32_t stage, const gpu::Buffer& input, const SolverOptions& o,
                  int iterations, uint32_t trials, uint32_t groups = 1, int arg = kDirect) const {
    rec.bind(*pcg);
    rec.set_storage_buffer(0, input);
    rec.set_storage_buffer(1, state);
    rec.set_storage_buffer(2, xs);
    rec.set_storage_buffer(3, track_params());
    rec.push_constants(PcgPush{stage, n, static_cast<uint32_t>(iterations), trials,
                               static_cast<uint32_t>(layout.offset(Block::kExpression)),
                               static_cast<uint32_t>(layout.num_expression), o.clamp_expression ? 1u : 0u, groups,
                               static_cast<float>(o.pcg_relative_tolerance), static_cast<float>(o.damping)});
    dispatch(rec, arg, 1, 1);
  }

  void ensure_assembled_buffers() {
    ensure(jtj_partials, VkDeviceSize{std::max(jtj_chunks(), 1u)} * entry_count() * 4, gpu::BufferDomain::Device,
           "tracker J^T J partials");
    ensure(jtj_reduced, VkDeviceSize{entry_count()} * 4, gpu::BufferDomain::Device, "tracker J^T J | J^T r");
  }

  // A submission's first barrier: everything before it (the render, earlier passes, host
  // writes) is complete and visible.
  static void record_after_everything_before(gpu::CommandRecorder& rec) {
    rec.memory_barrier(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT);
  }

  // After the compute passes: `first` (its first `first_bytes`, when given) into the readback
  // buffer's start and the energy partials (`partial_bytes`) after it, visible to the host.
  void record_readback(gpu::CommandRecorder& rec, VkCommandBuffer cmd, const gpu::Buffer* first,
                       VkDeviceSize first_bytes, VkDeviceSize partial_bytes) const {
    rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_READ_BIT);
    const VkBufferCopy copies[2] = {{0, 0, first_bytes}, {0, first_bytes, partial_bytes}};
    if (first) vkCmdCopyBuffer(cmd, first->handle(), readback.handle(), 1, &copies[0]);
    if (partial_bytes > 0) vkCmdCopyBuffer(cmd, energy_partials.handle(), readback.handle(), 1, &copies[1]);
    rec.memory_barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_2_HOST_BIT,
                       VK_ACCESS_2_HOST_READ_BIT);
  }

  // Uploads the x slots [0, points.size()) (float).
  void write_points(const std::vector<const Eigen::VectorXd*>& points) {
    std::vector<float> xf(points.size() * n);
    for (size_t k = 0; k < points.size(); ++k) {
      for (uint32_t i = 0; i < n; ++i) xf[k * n + i] = static_cast<float>((*points[k])[i]);
    }
    xs.write(xf.data(), xf.size() * sizeof(float));
  }

  // The per-term energies of x slot `slot` (summed in double) from the per-workgroup partials.
  static TermEnergies slot_energy(const std::vector<float>& partials, uint32_t slot, uint32_t groups) {
    TermEnergies e;
    for (uint32_t g = 0; g < groups; ++g) {
      for (int t = 0; t < kNumTerms; ++t) e.value[t] += partials[(static_cast<size_t>(slot) * groups + g) * 5 + t];
    }
    return e;
  }

  // [J^T J | J^T r] as tracker_jtj.comp packs it (n rows of n + 1) into the undamped J^T J, J^T r.
  void unpack_normal_equations(const std::vector<float>& packed, Eigen::MatrixXd* jtj, Eigen::VectorXd* jtr) const {
    jtj->resize(n, n);
    jtr->resize(n);
    for (uint32_t a = 0; a < n; ++a) {
      for (uint32_t b = 0; b < n; ++b) (*jtj)(a, b) = packed[static_cast<size_t>(a) * (n + 1) + b];
      (*jtr)[a] = packed[static_cast<size_t>(a) * (n + 1) + n];
    }
  }

  // The current linearisation's J^T J and J^T r at x, assembled on the device and read back (a
  // joint calibration sums them over its frames on the host), with the energy at x.
  struct NormalEquations {
    TermEnergies energy;
    Eigen::MatrixXd jtj;  // undamped
    Eigen::VectorXd jtr;
    double wall_ms = 0;
  };
  NormalEquations assemble(const Eigen::VectorXd& x) {
    const auto start = Clock::now();
    ensure_system_buffers(true, 1);
    ensure_assembled_buffers();
    write_points({&x});
    const uint32_t groups = evaluate_groups();
    const VkDeviceSize system_bytes = VkDeviceSize{entry_count()} * 4, partial_bytes = VkDeviceSize{groups} * 5 * 4;
    ensure(readback, system_bytes + partial_bytes, gpu::BufferDomain::Readback, "tracker readback");
    const bool rows = counts.rows() > 0;
    context.submit_and_wait(
        [&](VkCommandBuffer cmd) {
          gpu::CommandRecorder rec(context, cmd);
          record_after_everything_before(rec);
          record_evaluate(rec, 0, 1u);
          if (rows) {
            compute_barrier(rec);
            record_jtj(rec);
            compute_barrier(rec);
            record_reduce(rec, jtj_partials, jtj_reduced, entry_count(), jtj_chunks());
          }
          record_readback(rec, cmd, rows ? &jtj_reduced : nullptr, system_bytes, partial_bytes);
        },
        "tracker J^T J of one calibration frame");
    NormalEquations out;
    std::vector<float> packed(entry_count(), 0.f), partials(static_cast<size_t>(groups) * 5);
    if (rows) readback.read(packed.data(), packed.size() * sizeof(float));
    if (groups > 0) readback.read(partials.data(), partials.size() * sizeof(float), system_bytes);
    unpack_normal_equations(packed, &out.jtj, &out.jtr);
    out.energy = slot_energy(partials, 0, groups);
    out.wall_ms = ms_since(start);
    return out;
  }

  // The energies of the current linearisation (its correspondences held) at each of `points`,
  // in one submission.
  std::vector<TermEnergies> energies_at(const std::vector<Eigen::VectorXd>& points) {
    const uint32_t slots = static_cast<uint32_t>(points.size());
    ensure_system_buffers(false, slots);
    std::vector<const Eigen::VectorXd*> pointers;
    for (const Eigen::VectorXd& p : points) pointers.push_back(&p);
    write_points(pointers);
    const uint32_t groups = evaluate_groups();
    const VkDeviceSize partial_bytes = VkDeviceSize{slots} * groups * 5 * 4;
    ensure(readback, partial_bytes, gpu::BufferDomain::Readback, "tracker readback");
    context.submit_and_wait(
        [&](VkCommandBuffer cmd) {
          gpu::CommandRecorder rec(context, cmd);
          record_after_everything_before(rec);
          record_evaluate(rec, 0, 0u, slots);
          record_readback(rec, cmd, nullptr, 0, partial_bytes);
        },
        "tracker energies");
    std::vector<float> partials(static_cast<size_t>(slots) * groups * 5);
    if (groups > 0) readback.read(partials.data(), partials.size() * sizeof(float));
    std::vector<TermEnergies> out;
    for (uint32_t k = 0; k < slots; ++k) out.push_back(slot_energy(partials, k, groups));
    return out;
  }

  // Energy at x and, when `solve`, the PCG step and the energies of its trial scalings, in one
  // submission. Reads back only the energies, dx and the PCG summary.
  Analysis analyze(const Eigen::VectorXd& x, bool solve, VulkanStrategy strategy, const SolverOptions& o,
                   int pcg_iterations) {
    const auto start = Clock::now();
    const uint32_t trials = solve ? static_cast<uint32_t>(o.max_step_halvings) + 1 : 0;
    const uint32_t slots = 1 + trials;
    ensure_system_buffers(solve, slots);
    const bool assembled = strategy == VulkanStrategy::kAssembled;
    if (solve && assembled) ensure_assembled_buffers();
    write_points({&x});
    const uint32_t groups = evaluate_groups();
    const VkDeviceSize partial_bytes = VkDeviceSize{slots} * groups * 5 * 4;
    const VkDeviceSize state_bytes = (kStateX + n) * 4;
    ensure(readback, state_bytes + partial_bytes, gpu::BufferDomain::Readback, "tracker readback");
    context.submit_and_wait(
        [&](VkCommandBuffer cmd) {
          gpu::CommandRecorder rec(context, cmd);
          record_after_everything_before(rec);
          if (profile) {
            profile->reset(cmd);
            profile->write(cmd, 0);
          }
          record_evaluate(rec, 0, solve ? 1u : 0u);
          if (profile) profile->write(cmd, 1);
          if (solve) {
            compute_barrier(rec);
            if (assembled) {
              record_jtj(rec);
              compute_barrier(rec);
              record_reduce(rec, jtj_partials, jtj_reduced, entry_count(), jtj_chunks());
              compute_barrier(rec);
              record_pcg(rec, 1, jtj_reduced, o, pcg_iterations, 0);
            } else {
              // The PCG stages sum the per-chunk partials themselves (no reduction pass).
              record_jt(rec, 0);
              compute_barrier(rec);
              record_pcg(rec, 0, jt_partials, o, pcg_iterations, 0, jt_chunks());
              for (int it = 0; it < pcg_iterations; ++it) {
                compute_barrier(rec);
                record_jt(rec, 1);
                compute_barrier(rec);
                record_pcg(rec, 2, jt_partials, o, pcg_iterations, 0, jt_chunks());
              }
            }
            if (profile) profile->write(cmd, 2);
            compute_barrier(rec);
            record_pcg(rec, 3, reduced, o, pcg_iterations, trials);
            compute_barrier(rec);
            record_evaluate(rec, 1, 0u, trials);
          }
          if (profile) profile->write(cmd, 3);
          record_readback(rec, cmd, solve ? &state : nullptr, state_bytes, partial_bytes);
        },
        solve ? "tracker analysis + PCG" : "tracker energy");
    if (profile) {
      profile->fetch();
      std::fprintf(stderr, "tracker %s: %llu rows, evaluate %.2f ms, solve %.2f ms, trials %.2f ms, wall %.2f ms\n",
                   solve ? (assembled ? "assembled" : "matrix-free") : "energy",
                   static_cast<unsigned long long>(counts.rows()), profile->elapsed_ms(0, 1),
                   solve ? profile->elapsed_ms(1, 2) : 0.0, solve ? profile->elapsed_ms(2, 3) : 0.0, ms_since(start));
    }
    Analysis a;
    std::vector<float> partials(static_cast<size_t>(slots) * groups * 5);
    if (groups > 0) readback.read(partials.data(), partials.size() * sizeof(float), state_bytes);
    auto energy_of = [&](uint32_t slot) { return slot_energy(partials, slot, groups); };
    a.energy = energy_of(0);
    if (solve) {
      std::vector<float> st(kStateX + n);
      readback.read(st.data(), st.size() * sizeof(float));
      a.dx.resize(n);
      for (uint32_t i = 0; i < n; ++i) a.dx[i] = st[kStateX + i];
      a.pcg.iterations = static_cast<int>(st[kIterations]);
      a.pcg.initial_residual_norm = st[kInitialNorm];
      a.pcg.final_residual_norm = st[kFinalNorm];
      a.pcg.converged = st[kConverged] != 0.f;
      for (uint32_t h = 0; h < trials; ++h) a.trials.push_back(energy_of(1 + h));
    }
    a.wall_ms = ms_since(start);
    return a;
  }

  VulkanStrategy resolve(const SolverOptions& o) const {
    switch (options.strategy) {
      case VulkanStrategy::kFromSolverOptions:
        return o.linear_solver == LinearSolverType::kAssembled ? VulkanStrategy::kAssembled : VulkanStrategy::kMatrixFree;
      case VulkanStrategy::kAuto: return choice.chosen;  // kAuto until measured
      default: return options.strategy;
    }
  }

  // The solve's analysis, measuring both strategies the first time kAuto needs one.
  Analysis analyze_step(const Eigen::VectorXd& x, const SolverOptions& o, int pcg_iterations) {
    VulkanStrategy s = resolve(o);
    if (s != VulkanStrategy::kAuto) return analyze(x, true, s, o, pcg_iterations);
    analyze(x, true, VulkanStrategy::kMatrixFree, o, pcg_iterations);  // untimed: first touch of the buffers
    Analysis assembled = analyze(x, true, VulkanStrategy::kAssembled, o, pcg_iterations);
    Analysis matrix_free = analyze(x, true, VulkanStrategy::kMatrixFree, o, pcg_iterations);
    choice.matrix_free_ms = matrix_free.wall_ms;
    choice.assembled_ms = assembled.wall_ms;
    choice.residuals = counts.residuals();
    choice.chosen = matrix_free.wall_ms <= assembled.wall_ms ? VulkanStrategy::kMatrixFree : VulkanStrategy::kAssembled;
    return choice.chosen == VulkanStrategy::kMatrixFree ? matrix_free : assembled;
  }

  // Whether Solve drives this frame's loop from the device (solve_device_loop): on by default
  // once the strategy is known (kAuto times both on a first, host-driven step), and not when a
  // stop is already requested (the host loop ends before its first iteration).
  bool device_loop_applies(const SolverOptions& o) const {
    return options.device_loop && resolve(o) != VulkanStrategy::kAuto && !o.stop.stop_requested() &&
           !o.schedule.empty() && o.schedule.size() <= kMaxDeviceLoopLevels;
  }

  // The frame's whole schedule recorded into one command buffer and submitted once: per level,
  // blocks 0 .. iterations, each a render at x, its linearisation, and (while the level goes on)
  // the PCG step and its trial energies, with tracker_loop.comp's three stages making
  // RunGaussNewton's decisions between them on the device. The host reads x and the records
  // back once. Returns nothing when a linearisation needed more rows than J holds: J grows for
  // the next frame and the caller solves this one host-driven.
  std::optional<SolverSummary> solve_device_loop(const ParameterLayout& l, const SolverOptions& o,
                                                 std::unordered_map<int, LevelInput>& inputs,
                                                 const gpu::FaceParameters& base_params, Eigen::VectorXd* x) {
    const auto start = Clock::now();
    const EnergyOptions& e = o.energy;
    const bool assembled = resolve(o) == VulkanStrategy::kAssembled;
    const uint32_t trials = static_cast<uint32_t>(o.max_step_halvings) + 1, slots = 1 + trials;
    const uint32_t regularizer = e.use_regularizer ? static_cast<uint32_t>(RegularizerRows(l, true)) : 0;
    cache_identity = l.num_identity == 0 && l.num_albedo == 0;
    counts = Counts{};
    layout = l;
    n = static_cast<uint32_t>(l.num_parameters());
    // Sizes: the largest scheduled level; J with `capacity` rows.
    uint64_t max_pixels = 0, max_items = 0, rows_bound = 0;
    uint32_t blocks = 0, max_records = 0;
    for (const LevelSchedule& s : o.schedule) {
      const LevelInput& li = inputs.at(s.level);
      const uint64_t pixels = uint64_t(li.frame->width()) * li.frame->height();
      max_pixels = std::max(max_pixels, pixels);
      max_items = std::max(max_items, pixels + li.num_candidates + regularizer);
      rows_bound = std::max<uint64_t>(rows_bound, kRowsPerPixel * pixels + 2ull * li.num_candidates + regularizer);
      blocks += static_cast<uint32_t>(s.gauss_newton_iterations) + 1;
      max_records += static_cast<uint32_t>(s.gauss_newton_iterations);
    }
    const VkDeviceSize range = context.properties().limits.maxStorageBufferRange;
    const uint64_t range_rows = range / (4ull * n) / 4 * 4;
    if (loop_capacity_rows == 0) {
      loop_capacity_rows = options.device_loop_rows > 0 ? options.device_loop_rows : kDeviceLoopJacobianBudget / (4ull * n) / 4 * 4;
    }
    const uint64_t capacity = std::min({loop_capacity_rows, (rows_bound + 3) / 4 * 4, range_rows});
    ensure_pixel_buffers(max_pixels);
    ensure(xs, VkDeviceSize{slots} * n * 4, gpu::BufferDomain::Upload, "tracker parameter vectors");
    ensure(vertices, VkDeviceSize{slots} * model.num_vertices() * 24, gpu::BufferDomain::Device, "tracker vertices");
    ensure(residuals, capacity * 4, gpu::BufferDomain::Device, "tracker residuals");
    ensure(jacobian, 16, gpu::BufferDomain::Device, "tracker Jacobian (row-major)");
    ensure(jacobian_columns, capacity * n * 4, gpu::BufferDomain::Device, "tracker Jacobian (column-major)");
    ensure(energy_partials, VkDeviceSize{slots} * ((max_items + kEvaluateGroup - 1) / kEvaluateGroup) * 5 * 4,
           gpu::BufferDomain::Device, "tracker energy partials");
    ensure(jt_partials, (capacity + kJtChunk - 1) / kJtChunk * 2 * n * 4, gpu::BufferDomain::Device,
           "tracker J^T partials");
    ensure(reduced, VkDeviceSize{2} * n * 4, gpu::BufferDomain::Device, "tracker J^T r | diag");
    if (assembled) {
      ensure(jtj_partials, (capacity + kJtjRowsPerChunk - 1) / kJtjRowsPerChunk * entry_count() * 4,
             gpu::BufferDomain::Device, "tracker J^T J partials");
      ensure(jtj_reduced, VkDeviceSize{entry_count()} * 4, gpu::BufferDomain::Device, "tracker J^T J | J^T r");
    }
    const VkDeviceSize loop_bytes = (kLoopRecordBase + VkDeviceSize{max_records} * kLoopRecordFloats) * 4;
    ensure(loop_state, loop_bytes, gpu::BufferDomain::Device, "tracker loop state");
    ensure(readback, loop_bytes, gpu::BufferDomain::Readback, "tracker readback");
    while (level_params.size() < o.schedule.size()) {
      level_params.emplace_back(context, sizeof(TrackParams), kStorage, gpu::BufferDomain::Upload, "tracker level parameters");
    }
    // What the host knows ahead: x, the base, each level's camera and model sizes.
    write_points({x});
    std::vector<gpu::Renderer::DeviceRenderSizes> render_sizes;
    for (size_t li = 0; li < o.schedule.size(); ++li) {
      const InputFrame& f = *inputs.at(o.schedule[li].level).frame;
      write_params(Counts{}, l, base_params, e, f.camera, true, &level_params[li]);
      render_sizes.push_back(renderer.prepare_device_render(f.camera, o.render));
    }
    std::array<float, kLoopHeader> header{};
    header[kLoopRunning] = 1.f;
    header[kLoopOpenRecord] = -1.f;
    for (size_t li = 0; li < kMaxDeviceLoopLevels; ++li) header[kLoopConvergedAt + li] = -1.f;
    const gpu::Renderer::IndirectStages stages{&loop_args, 16 * kArgIdentity, 16 * kArgModel, 16 * kArgShade,
                                               16 * kArgDraw};
    const uint32_t vertex_mode = cache_identity ? 2u : 0u;
    // Blocks per level: the first of each in the frame's numbering, all of them, and how many to
    // record (as many as the last frames needed; all while there is no history).
    std::vector<int> schedule_key;
    for (const LevelSchedule& s : o.schedule) schedule_key.insert(schedule_key.end(), {s.level, s.gauss_newton_iterations});
    std::vector<std::deque<uint32_t>>& history = loop_history[schedule_key];
    history.resize(o.schedule.size());
    std::vector<uint32_t> first_block, all_blocks, predicted;
    for (uint32_t b = 0, li = 0; li < o.schedule.size(); ++li) {
      first_block.push_back(b);
      all_blocks.push_back(static_cast<uint32_t>(o.schedule[li].gauss_newton_iterations) + 1);
      const auto& h = history[li];
      predicted.push_back(h.empty() ? all_blocks[li] : std::min(all_blocks[li], *std::max_element(h.begin(), h.end())));
      b += all_blocks[li];
    }
    std::vector<double> synthesis(blocks, 0.0), analysis(blocks, 0.0);
    std::vector<float> st(loop_bytes / 4);
    size_t start_level = 0;
    uint32_t start_block = 0;
    for (bool first_chunk = true;; first_chunk = false) {
      // This submission: from (start_level, start_block), each level up to its predicted end (the
      // resumed level to its last block).
      std::vector<uint32_t> end(o.schedule.size(), 0);
      uint32_t recorded = 0;
      for (size_t li = start_level; li < o.schedule.size(); ++li) {
        const uint32_t begin = li == start_level ? start_block : 0;
        end[li] = li == start_level && !first_chunk ? all_blocks[li] : std::max(begin + 1, predicted[li]);
        recorded += end[li] - begin;
      }
      gpu::TimestampQueries* stamps = loop_timestamps && 2 * recorded + 1 <= 32 ? loop_timestamps.get() : nullptr;
      std::vector<uint32_t> stamped;  // the frame's block number of each recorded block, in order
      context.submit_and_wait(
          [&](VkCommandBuffer cmd) {
            gpu::CommandRecorder rec(context, cmd);
            record_after_everything_before(rec);
            if (first_chunk) {
              vkCmdUpdateBuffer(cmd, loop_state.handle(), 0, sizeof(header), header.data());
            } else {
              const float resume = 0.f;
              vkCmdUpdateBuffer(cmd, loop_state.handle(), 4 * kLoopSuspended, sizeof(resume), &resume);
            }
            rec.memory_barrier(VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                               VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                               VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
            if (stamps) {
              stamps->reset(cmd);
              stamps->write(cmd, 0);
            }
            device_params = &level_params[0];
            if (first_chunk && cache_identity) {  // the base's identity and albedo: the same for the whole frame
              record_vertices(rec, 0, 1, 1);
              compute_barrier(rec);
            }
            // After a loop stage: its writes visible to the next passes, their indirect arguments included.
            auto loop_barrier = [&] {
              rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                                 VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT |
                                     VK_PIPELINE_STAGE_2_VERTEX_SHADER_BIT,
                                 VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT |
                                     VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
            };
            uint32_t stamp = 1;
            for (size_t li = start_level; li < o.schedule.size(); ++li) {
              const LevelSchedule& s = o.schedule[li];
              LevelInput& in = inputs.at(s.level);
              const InputFrame& f = *in.frame;
              current_input = &in.data;
              device_params = &level_params[li];
              LoopPush push{};
              push.level_index = static_cast<uint32_t>(li);
              push.iterations = static_cast<uint32_t>(s.gauss_newton_iterations);
              push.level = static_cast<uint32_t>(s.level);
              push.first_level = li == 0 ? 1u : 0u;
              push.num_trials = trials;
              push.identity_every_block = cache_identity ? 0u : 1u;
              push.vertex_groups = render_sizes[li].model_groups;
              push.tracker_vertex_groups = vertex_groups();
              push.shade_groups = render_sizes[li].shade_groups;
              push.draw_vertices = render_sizes[li].draw_vertices;
              push.classify_groups = static_cast<uint32_t>((uint64_t(f.width()) * f.height() + 63) / 64);
              push.num_regularizer = regularizer;
              push.capacity_rows = static_cast<uint32_t>(capacity);
              push.assembled = assembled ? 1u : 0u;
              push.w_point = static_cast<float>(e.w_point);
              push.w_plane = static_cast<float>(e.w_plane);
              push.w_col = static_cast<float>(e.w_col);
              push.w_lan = static_cast<float>(e.w_lan);
              push.inverse_unit = static_cast<float>(1.0 / e.geometry_unit_m);
              push.landmark_scale = static_cast<float>(e.landmark_reference_width / f.camera.width);
              push.function_tolerance = static_cast<float>(o.function_tolerance);
              auto record_loop = [&](uint32_t stage) {
                rec.bind(*loop);
                const gpu::Buffer* b[] = {&track_params(), &xs,      &base,     &energy_partials,
                                          &state,          &counters, &loop_state, &loop_args,
                                          &renderer.device_coefficients(), &renderer.device_frame()};
                for (uint32_t i = 0; i < 10; ++i) rec.set_storage_buffer(i, *b[i]);
                push.stage = stage;
                rec.push_constants(push);
                rec.dispatch(1, 1, 1);
                loop_barrier();
              };
              const uint32_t begin = li == start_level ? start_block : 0;
              for (uint32_t block = begin; block < end[li]; ++block) {
                push.block = block;
                push.previous_cut = block == 0 && li > start_level && end[li - 1] < all_blocks[li - 1] ? 1u : 0u;
                // The last block's readers (the draw's vertex shader, the per-pixel pass) before
                // this block's writers (the shading pass, the G-buffer copies): what a submission
                // boundary ordered on the host-driven path.
                record_after_everything_before(rec);
                record_loop(0);  // prepare
                renderer.record_device_render(cmd, f.camera, o.render, stages);
                record_linearization(rec, renderer.targets(), in, e, true);
                compute_barrier(rec);
                record_loop(1);  // counts
                if (stamps) stamps->write(cmd, stamp++);
                record_vertices(rec, 0, vertex_mode, 1, kArgVertices);
                compute_barrier(rec);
                record_evaluate_pass(rec, 0, 1u, 1, kArgEvaluateJ);  // a step follows: J too
                compute_barrier(rec);
                record_evaluate_pass(rec, 0, 0u, 1, kArgEvaluateEnergy);  // the level's last linearisation
                compute_barrier(rec);
                if (assembled) {
                  record_jtj(rec, kArgJtj);
                  compute_barrier(rec);
                  record_reduce(rec, jtj_partials, jtj_reduced, entry_count(), kSizeFromParams, kArgReduce);
                  compute_barrier(rec);
                  record_pcg(rec, 1, jtj_reduced, o, s.pcg_iterations, 0, 1, kArgPcg);
                } else {
                  record_jt(rec, 0, kArgJt);
                  compute_barrier(rec);
                  record_pcg(rec, 0, jt_partials, o, s.pcg_iterations, 0, kSizeFromParams, kArgPcg);
                  for (int it = 0; it < s.pcg_iterations; ++it) {
                    compute_barrier(rec);
                    record_jt(rec, 1, kArgJt);
                    compute_barrier(rec);
                    record_pcg(rec, 2, jt_partials, o, s.pcg_iterations, 0, kSizeFromParams, kArgPcg);
                  }
                }
                compute_barrier(rec);
                record_pcg(rec, 3, reduced, o, s.pcg_iterations, trials, 1, kArgPcg);
                compute_barrier(rec);
                record_vertices(rec, 1, vertex_mode, trials, kArgTrialVertices);
                compute_barrier(rec);
                record_evaluate_pass(rec, 1, 0u, trials, kArgTrialEvaluate);
                compute_barrier(rec);
                record_loop(2);  // control
                if (stamps) stamps->write(cmd, stamp++);
                stamped.push_back(first_block[li] + block);
              }
            }
            rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                               VK_PIPELINE_STAGE_2_COPY_BIT | VK_PIPELINE_STAGE_2_HOST_BIT,
                               VK_ACCESS_2_TRANSFER_READ_BIT | VK_ACCESS_2_HOST_READ_BIT);
            const VkBufferCopy copy{0, 0, loop_bytes};
            vkCmdCopyBuffer(cmd, loop_state.handle(), readback.handle(), 1, &copy);
            rec.memory_barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_2_HOST_BIT,
                               VK_ACCESS_2_HOST_READ_BIT);
          },
          "tracker frame (device-driven Gauss-Newton loop)");
      device_params = nullptr;
      current_input = nullptr;
      readback.read(st.data(), loop_bytes);
      // Synthesis (render + linearisation) and analysis (the rest) per block, from the timestamps.
      if (stamps) {
        stamps->fetch();
        for (size_t k = 0; k < stamped.size(); ++k) {
          synthesis[stamped[k]] = stamps->elapsed_ms(static_cast<uint32_t>(2 * k), static_cast<uint32_t>(2 * k + 1));
          analysis[stamped[k]] = stamps->elapsed_ms(static_cast<uint32_t>(2 * k + 1), static_cast<uint32_t>(2 * k + 2));
        }
      }
      const int suspended = static_cast<int>(st[kLoopSuspended]);
      if (suspended == 0) break;
      start_level = static_cast<size_t>(suspended) - 1;  // its blocks after those recorded, then the levels after it
      start_block = end[start_level];
    }
    const auto termination = static_cast<DeviceTermination>(static_cast<int>(st[kLoopTermination]));
    if (termination == DeviceTermination::kOverflow) {
      // The rows that level needed, scaled to the largest scheduled level (the face covers about
      // the same share of each), and a quarter more.
      const InputFrame& f = *inputs.at(o.schedule[static_cast<size_t>(st[kLoopTermLevel])].level).frame;
      const double scale = static_cast<double>(max_pixels) / (double(f.width()) * f.height());
      const uint64_t needed = static_cast<uint64_t>(st[kLoopOverflowRows] * scale * 1.25);
      loop_capacity_rows = std::max(loop_capacity_rows, (needed + 3) / 4 * 4);
      return std::nullopt;
    }
    std::vector<float> xf(n);
    xs.read(xf.data(), xf.size() * sizeof(float));
    for (uint32_t i = 0; i < n; ++i) (*x)[i] = xf[i];
    SolverSummary summary;
    auto energy_at = [&](size_t at) {
      TermEnergies t;
      for (int k = 0; k < kNumTerms; ++k) t.value[k] = st[at + static_cast<size_t>(k)];
      return t;
    };
    summary.initial_energy = energy_at(kLoopInitial);
    summary.final_energy = energy_at(kLoopFinal);
    // The records, and each one's block: the first block of its level plus its iteration.
    const int records = static_cast<int>(st[kLoopRecords]);
    std::vector<uint32_t> records_per_level(o.schedule.size(), 0);
    for (int r = 0; r < records; ++r) {
      const size_t at = kLoopRecordBase + static_cast<size_t>(r) * kLoopRecordFloats;
      IterationRecord rec;
      rec.level = static_cast<int>(st[at]);
      rec.iteration = static_cast<int>(st[at + 1]);
      rec.residuals = static_cast<Eigen::Index>(st[at + 2]);
      rec.energy_before = energy_at(at + 3);
      rec.energy_after = energy_at(at + 8);
      rec.pcg_iterations = static_cast<int>(st[at + 13]);
      rec.pcg_relative_residual = st[at + 14];
      rec.step_norm = st[at + 15];
      rec.step_halvings = static_cast<int>(st[at + 16]);
      const size_t level_index = static_cast<size_t>(st[at + 17]);
      ++records_per_level[level_index];
      const uint32_t b = first_block[level_index] + static_cast<uint32_t>(rec.iteration);
      rec.analysis_ms = analysis[b];
      if (b + 1 < blocks) rec.synthesis_ms = synthesis[b + 1];
      summary.iterations.push_back(rec);
    }
    for (size_t li = 0; li < o.schedule.size(); ++li) {
      const int at = static_cast<int>(st[kLoopConvergedAt + li]);
      if (at >= 0) summary.message += internal::LevelConvergedWords(o.schedule[li].level, at);
    }
    // The blocks each level used (its steps and the linearisation after the last), for the next
    // frames' recording.
    if (termination == DeviceTermination::kDone) {
      for (size_t li = 0; li < o.schedule.size(); ++li) {
        auto& h = history[li];
        h.push_back(std::min(all_blocks[li], records_per_level[li] + 1));
        if (h.size() > kLoopHistoryFrames) h.pop_front();
      }
    }
    const int term_level = o.schedule[static_cast<size_t>(st[kLoopTermLevel])].level;
    const int term_iteration = static_cast<int>(st[kLoopTermIteration]);
    switch (termination) {
      case DeviceTermination::kNoDataAtStart:
        summary.termination = Termination::kNoValidResiduals;
        summary.message += internal::NoDataWords(term_level, 1);
        break;
      case DeviceTermination::kStepLostFace:
        summary.termination = Termination::kNoValidResiduals;
        summary.message += internal::StepLostFaceWords(term_level);
        break;
      case DeviceTermination::kNonFinite:
        summary.termination = Termination::kNonFinite;
        summary.message += internal::NonFiniteWords(term_level, term_iteration);
        break;
      default:
        internal::FinishSummary(static_cast<int>(o.schedule.size()), static_cast<int>(st[kLoopAccepted]),
                                static_cast<int>(st[kLoopAttempted]), &summary);
    }
    const double wall_ms = ms_since(start);
    for (uint32_t b = 0; b < blocks; ++b) summary.synthesis_ms += synthesis[b];
    summary.analysis_ms = wall_ms - summary.synthesis_ms;  // without timestamps: all of it
    return summary;
  }

  const gpu::Buffer* current_input = nullptr;
  // Per pyramid level, the input buffers of the frame being solved, kept for the next frame.
  std::unordered_map<int, LevelInput> level_inputs;

  class GaussNewton;
  class JointGaussNewton;
};

// The Gauss-Newton loop's work on the device (one frame). A linearisation that a step follows
// computes that step and its trial energies in the same submission (analyze_step), so
// SolveStep and TrialEnergy only hand over what that pass read back.
class VulkanSolver::Impl::GaussNewton final : public internal::GaussNewtonBackend {
 public:
  GaussNewton(Impl& m, const ParameterLayout& layout, const SolverOptions& options,
              std::unordered_map<int, LevelInput>& inputs, const gpu::FaceParameters& base)
      : m_(m), layout_(layout), options_(options), inputs_(inputs), base_(base) {}

  internal::Linearized Linearize(const LevelSchedule& level, const Eigen::VectorXd& x, bool step_follows,
                                 double* synthesis_ms, double* analysis_ms) override {
    LevelInput& li = inputs_.at(level.level);
    m_.current_input = &li.data;
    const Counts counts = m_.linearize(li, layout_, layout_.Unpack(x, base_), options_, synthesis_ms, analysis_ms);
    const bool solve = step_follows && counts.has_data();
    analysis_ = solve ? m_.analyze_step(x, options_, level.pcg_iterations)
                      : m_.analyze(x, false, VulkanStrategy::kMatrixFree, options_, level.pcg_iterations);
    // The fused pass's time belongs to the iteration that uses its step (as the CPU's Jacobian).
    if (solve) {
      step_ms_ = analysis_.wall_ms;
    } else {
      *analysis_ms += analysis_.wall_ms;
    }
    return {analysis_.energy, counts.residuals(), counts.has_data()};
  }

  void SolveStep(const LevelSchedule&, const Eigen::VectorXd& x, Eigen::VectorXd* dx, IterationRecord* rec) override {
    if (analysis_.dx.size() != x.size()) throw Error("Vulkan solver: a step was asked for that no analysis computed");
    *dx = analysis_.dx;
    rec->analysis_ms += TakeUnusedStepMs();
    rec->pcg_iterations = analysis_.pcg.iterations;
    rec->pcg_relative_residual = analysis_.pcg.initial_residual_norm > 0
                                     ? analysis_.pcg.final_residual_norm / analysis_.pcg.initial_residual_norm
                                     : 0;
  }

  // The device evaluated clamp(x + 2^-h dx) for every h in the same pass, as the loop forms x_try.
  double TrialEnergy(int halving, const Eigen::VectorXd&) override { return analysis_.trials.at(halving).total(); }

  double TakeUnusedStepMs() override { return std::exchange(step_ms_, 0.0); }

 private:
  Impl& m_;
  const ParameterLayout& layout_;
  const SolverOptions& options_;
  std::unordered_map<int, LevelInput>& inputs_;
  const gpu::FaceParameters& base_;
  Analysis analysis_;
  double step_ms_ = 0;
};

// The Gauss-Newton loop's work on the device for several frames solved jointly (calibration,
// Sec. 6.3). Per frame the device renders, linearises, evaluates J and assembles J^T J and J^T r
// over the frame's local unknowns (shared identity/albedo, then its own); the host sums them into
// the joint system, which is small (90 + 85 unknowns per frame with the default layout), and
// solves it with the CPU's Jacobi PCG (pcg.h). The matrix-free strategy would need every frame's
// J resident on the device at once. The step's trial energies (correspondences held) are
// evaluated on the device: each frame is rendered and linearised again at the step's start (the
// same render, so the same correspondences) and all halvings are evaluated in one submission.
class VulkanSolver::Impl::JointGaussNewton final : public internal::GaussNewtonBackend {
 public:
  JointGaussNewton(Impl& m, const ParameterLayout& layout, const SolverOptions& options,
                   const internal::JointUnknowns& unknowns, std::vector<std::unordered_map<int, LevelInput>>& inputs,
                   const std::vector<gpu::FaceParameters>& bases)
      : m_(m), layout_(layout), options_(options), unknowns_(unknowns), inputs_(inputs), bases_(bases) {
    scratch_.Resize(unknowns.size());
  }

  internal::Linearized Linearize(const LevelSchedule& level, const Eigen::VectorXd& x, bool step_follows,
                                 double* synthesis_ms, double* analysis_ms) override {
    level_ = level.level;
    x_ = x;
    held_frame_ = -1;
    systems_.clear();
    trial_points_.clear();
    trial_energies_.clear();
    internal::Linearized out;
    out.has_data = true;
    for (int f = 0; f < unknowns_.frames(); ++f) {
      const Eigen::VectorXd xf = unknowns_.FrameX(x, f);
      const Counts counts = linearize_frame(f, xf, synthesis_ms, analysis_ms);
      held_frame_ = f;
      out.has_data = out.has_data && counts.has_data();
      out.residuals += counts.residuals();
      TermEnergies e;
      if (step_follows) {
        NormalEquations ne = m_.assemble(xf);
        step_ms_ += ne.wall_ms;  // the step's time, booked by SolveStep (as the CPU's J)
        e = ne.energy;
        systems_.push_back(std::move(ne));
      } else {
        const auto t0 = Clock::now();
        e = m_.energies_at({xf}).front();
        *analysis_ms += ms_since(t0);
      }
      for (int t = 0; t < kNumTerms; ++t) out.energy.value[t] += e.value[t];
    }
    m_.current_input = nullptr;
    return out;
  }

  void SolveStep(const LevelSchedule& level, const Eigen::VectorXd& x, Eigen::VectorXd* dx,
                 IterationRecord* rec) override {
    if (static_cast<int>(systems_.size()) != unknowns_.frames() || x.size() != unknowns_.size()) {
      throw Error("Vulkan solver: a step was asked for that no linearisation prepared");
    }
    const auto start = Clock::now();
    rec->analysis_ms += TakeUnusedStepMs();
    const int n = unknowns_.size(), local = unknowns_.shared() + unknowns_.own();
    Eigen::MatrixXd jtj = Eigen::MatrixXd::Zero(n, n);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(n);
    for (int f = 0; f < unknowns_.frames(); ++f) {
      const NormalEquations& ne = systems_[static_cast<size_t>(f)];
      for (int a = 0; a < local; ++a) {
        const int ga = unknowns_.Global(a, f);
        b[ga] -= ne.jtr[a];
        for (int c = 0; c < local; ++c) jtj(ga, unknowns_.Global(c, f)) += ne.jtj(a, c);
      }
    }
    const AssembledNormalOperator op(std::move(jtj), options_.damping);
    dx->setZero(n);
    const PcgSummary ps = Pcg(op, b, PcgOptions{level.pcg_iterations, options_.pcg_relative_tolerance}, &scratch_, dx);
    dx_ = *dx;
    rec->analysis_ms += ms_since(start);
    rec->pcg_iterations = ps.iterations;
    rec->pcg_relative_residual = ps.initial_residual_norm > 0 ? ps.final_residual_norm / ps.initial_residual_norm : 0;
  }

  // Every halving's trial point is formed as the loop forms it (x + 2^-h dx, expression clamped).
  // The full step is evaluated alone and, only if the loop goes on to halve it, all halvings in
  // one more pass: most steps are taken whole, and each trial point is a render and an evaluation
  // of every frame (on lavapipe evaluating all of them with the first made the trials 60 % of a
  // calibration step). Each pass re-linearises every frame but the one the device still holds.
  double TrialEnergy(int halving, const Eigen::VectorXd& x_try) override {
    if (trial_points_.empty()) {
      double scale = 1.0;
      for (int h = 0; h <= options_.max_step_halvings; ++h, scale *= 0.5) {
        Eigen::VectorXd p = x_ + scale * dx_;
        internal::ClampExpressions(options_, unknowns_.ExpressionSpans(), &p);
        trial_points_.push_back(std::move(p));
      }
    }
    const size_t h = static_cast<size_t>(halving);
    if (halving < 0 || h >= trial_points_.size() || trial_points_[h] != x_try) {
      return Evaluate({x_try}).front();  // a point the loop formed otherwise (not expected)
    }
    if (h >= trial_energies_.size()) {
      const size_t first = trial_energies_.size(), end = first == 0 ? 1 : trial_points_.size();
      const std::vector<double> e =
          Evaluate(std::vector<Eigen::VectorXd>(trial_points_.begin() + static_cast<std::ptrdiff_t>(first),
                                                trial_points_.begin() + static_cast<std::ptrdiff_t>(end)));
      trial_energies_.insert(trial_energies_.end(), e.begin(), e.end());
    }
    return trial_energies_[h];
  }

  double TakeUnusedStepMs() override { return std::exchange(step_ms_, 0.0); }

 private:
  Counts linearize_frame(int f, const Eigen::VectorXd& xf, double* synthesis_ms, double* analysis_ms) {
    LevelInput& li = inputs_[static_cast<size_t>(f)].at(level_);
    m_.current_input = &li.data;
    return m_.linearize(li, layout_, layout_.Unpack(xf, bases_[static_cast<size_t>(f)]), options_, synthesis_ms,
                        analysis_ms, /*regularize_shared=*/f == 0);
  }

  // Total energies at joint points, each frame linearised at the step's start: the frame the
  // device still holds first (its linearisation at x_ is in place), then the others linearised
  // again. Summed in frame order, whichever order they were evaluated in.
  std::vector<double> Evaluate(const std::vector<Eigen::VectorXd>& points) {
    const int frames = unknowns_.frames();
    std::vector<int> order;
    if (held_frame_ >= 0) order.push_back(held_frame_);
    for (int f = 0; f < frames; ++f) {
      if (f != held_frame_) order.push_back(f);
    }
    std::vector<std::vector<TermEnergies>> per_frame(static_cast<size_t>(frames));
    double unused = 0;
    for (const int f : order) {
      if (f == held_frame_) {
        m_.current_input = &inputs_[static_cast<size_t>(f)].at(level_).data;
      } else {
        linearize_frame(f, unknowns_.FrameX(x_, f), &unused, &unused);
        held_frame_ = f;
      }
      std::vector<Eigen::VectorXd> local;
      for (const Eigen::VectorXd& p : points) local.push_back(unknowns_.FrameX(p, f));
      per_frame[static_cast<size_t>(f)] = m_.energies_at(local);
    }
    std::vector<double> totals(points.size(), 0.0);
    for (const std::vector<TermEnergies>& e : per_frame) {
      for (size_t k = 0; k < points.size(); ++k) totals[k] += e[k].total();
    }
    m_.current_input = nullptr;
    return totals;
  }

  Impl& m_;
  const ParameterLayout& layout_;
  const SolverOptions& options_;
  const internal::JointUnknowns& unknowns_;
  std::vector<std::unordered_map<int, LevelInput>>& inputs_;
  const std::vector<gpu::FaceParameters>& bases_;
  PcgScratch scratch_;
  int level_ = 0;
  // The frame whose linearisation at x_ (level_) the device holds (-1: none): the last one
  // linearised, since each frame's linearisation replaces the one before on the device.
  int held_frame_ = -1;
  Eigen::VectorXd x_, dx_;  // the last linearisation point and the step solved there
  std::vector<NormalEquations> systems_;
  std::vector<Eigen::VectorXd> trial_points_;
  std::vector<double> trial_energies_;
  double step_ms_ = 0;
};

VulkanSolver::VulkanSolver(const gpu::Context& context, TrackerModel model, const VulkanSolverOptions& options)
    : impl_(std::make_unique<Impl>(context, std::move(model), options)) {
  impl_->init();
}

VulkanSolver::~VulkanSolver() = default;

const TrackerModel& VulkanSolver::model() const { return impl_->model; }
const VulkanSolverOptions& VulkanSolver::options() const { return impl_->options; }
const VulkanStrategyChoice& VulkanSolver::strategy_choice() const { return impl_->choice; }

void VulkanSolver::set_strategy(VulkanStrategy strategy) {
  VulkanSolverOptions o = impl_->options;
  o.strategy = strategy;
  std::string why;
  if (!o.IsValid(&why)) throw Error(why);
  impl_->options = o;
  impl_->choice = VulkanStrategyChoice{};
}

// Solve's arguments, checked before anything is uploaded.
void VulkanSolver::CheckSolveArguments(const ParameterLayout& layout, const SolverOptions& options,
                                       const gpu::FaceParameters* params) const {
  const TrackerModel& model = impl_->model;
  std::string why;
  if (!params) throw Error("Vulkan solver: no parameters given");
  if (!options.IsValid(&why)) throw Error(why);
  if (!layout.IsValid(&why, model.num_identity(), model.num_albedo(), model.num_expression())) throw Error(why);
  if (layout.num_parameters() > static_cast<int>(kMaxUnknowns)) {
    throw Error("Vulkan solver: " + std::to_string(layout.num_parameters()) + " unknowns, the device passes support at most " +
                std::to_string(kMaxUnknowns));
  }
  if (!params->IsValid(&why, model.num_identity(), model.num_expression(), model.num_albedo())) {
    throw Error("tracker start parameters: " + why);
  }
}

SolverSummary VulkanSolver::Solve(const InputFrame& frame, const ParameterLayout& layout, const SolverOptions& options,
                                  gpu::FaceParameters* params) {
  CheckSolveArguments(layout, options, params);
  Impl& m = *impl_;
  const auto start = Clock::now();
  const std::vector<InputFrame> levels = PyramidLevelsWithoutPixels(frame, options.pyramid);
  const double pyramid_ms = ms_since(start);
  m.prepare_pyramid_on_device(frame, levels, options, m.level_inputs);
  SolverSummary summary = SolvePrepared(layout, options, params, ms_since(start) - pyramid_ms);
  summary.pyramid_ms = pyramid_ms;
  summary.total_ms = ms_since(start);
  return summary;
}

SolverSummary VulkanSolver::Solve(const std::vector<InputFrame>& pyramid, const ParameterLayout& layout,
                                  const SolverOptions& options, gpu::FaceParameters* params) {
  CheckSolveArguments(layout, options, params);
  Impl& m = *impl_;
  std::string why;
  for (const auto& level : options.schedule) {
    if (level.level >= static_cast<int>(pyramid.size())) throw Error("solver: the pyramid has fewer levels than the schedule uses");
    if (!pyramid[level.level].IsValid(&why)) throw Error(why);
  }
  const auto start = Clock::now();
  std::unordered_map<int, bool> prepared;
  for (const auto& level : options.schedule) {
    if (prepared[level.level]) continue;
    m.prepare_level(pyramid[level.level], options.energy, options.threads, &m.level_inputs[level.level]);
    prepared[level.level] = true;
  }
  SolverSummary summary = SolvePrepared(layout, options, params, ms_since(start));
  summary.total_ms = ms_since(start);
  return summary;
}

// The frame's solve once its levels are prepared (m.level_inputs).
SolverSummary VulkanSolver::SolvePrepared(const ParameterLayout& layout, const SolverOptions& options,
                                          gpu::FaceParameters* params, double input_ms) {
  Impl& m = *impl_;
  const SubmissionMeter submissions(m.context);
  const gpu::FaceParameters base = *params;
  Eigen::VectorXd x = layout.Pack(base);
  std::unordered_map<int, LevelInput>& inputs = m.level_inputs;
  std::optional<SolverSummary> device_driven;
  if (m.device_loop_applies(options)) device_driven = m.solve_device_loop(layout, options, inputs, base, &x);
  SolverSummary summary;
  if (device_driven) {
    summary = std::move(*device_driven);
  } else {
    Impl::GaussNewton backend(m, layout, options, inputs, base);
    summary = internal::RunGaussNewton(options, {{layout.offset(Block::kExpression), layout.num_expression}}, 1, &backend,
                                       &x);
  }
  const VulkanStrategy used = m.resolve(options);
  summary.message += std::string("; Vulkan (") + m.context.device_info().name + ", " + vulkan_strategy_name(used) +
                     (device_driven ? ", device-driven loop" : "") + ")";
  *params = layout.Unpack(x, base);
  summary.input_ms = input_ms;
  submissions.Fill(&summary);
  m.current_input = nullptr;
  return summary;
}

SolverSummary VulkanSolver::SolveFrames(const std::vector<InputFrame>& frames, const ParameterLayout& layout,
                                        const SolverOptions& options, std::vector<gpu::FaceParameters>* params) {
  Impl& m = *impl_;
  std::string why;
  if (!params) throw Error("Vulkan solver: no parameters given");
  if (!options.IsValid(&why)) throw Error(why);
  if (frames.empty()) throw Error("calibration: no frames");
  if (layout.num_parameters() > static_cast<int>(kMaxUnknowns)) {
    throw Error("Vulkan solver: " + std::to_string(layout.num_parameters()) +
                " unknowns per frame, the device passes support at most " + std::to_string(kMaxUnknowns));
  }
  const auto start = Clock::now();
  const SubmissionMeter submissions(m.context);
  const internal::FramePyramids pyramids = internal::BuildFramePyramids(frames, options);
  internal::CheckJointSolve(m.model, layout, options, pyramids.pointers, *params);
  const auto solve_start = Clock::now();
  // Each frame's levels, uploaded once for the whole calibration.
  std::vector<std::unordered_map<int, LevelInput>> inputs(frames.size());
  for (size_t f = 0; f < frames.size(); ++f) {
    for (const auto& level : options.schedule) {
      if (inputs[f].count(level.level)) continue;
      m.prepare_level(pyramids.pyramids[f][static_cast<size_t>(level.level)], options.energy, options.threads,
                      &inputs[f][level.level]);
    }
  }
  const double input_ms = ms_since(solve_start);
  const internal::JointUnknowns unknowns(layout, static_cast<int>(frames.size()));
  const std::vector<gpu::FaceParameters> bases = *params;
  Eigen::VectorXd x = unknowns.Pack(bases);
  Impl::JointGaussNewton backend(m, layout, options, unknowns, inputs, bases);
  SolverSummary summary = internal::RunGaussNewton(options, unknowns.ExpressionSpans(), unknowns.frames(), &backend, &x);
  summary.message += std::string("; Vulkan (") + m.context.device_info().name +
                     ", J^T J per frame on the device, the joint system on the host)";
  for (int f = 0; f < unknowns.frames(); ++f) (*params)[static_cast<size_t>(f)] = layout.Unpack(unknowns.FrameX(x, f), bases[static_cast<size_t>(f)]);
  summary.pyramid_ms = pyramids.ms;
  summary.input_ms = input_ms;
  summary.total_ms = ms_since(start);
  submissions.Fill(&summary);
  return summary;
}

VulkanLinearSystem VulkanSolver::Inspect(const InputFrame& level_frame, const ParameterLayout& layout,
                                         const EnergyOptions& energy, const gpu::FaceParameters& params,
                                         const Eigen::VectorXd& v, const gpu::RenderOptions& render) {
  Impl& m = *impl_;
  std::string why;
  if (!level_frame.IsValid(&why)) throw Error(why);
  if (!energy.IsValid(&why)) throw Error(why);
  if (!layout.IsValid(&why, m.model.num_identity(), m.model.num_albedo(), m.model.num_expression())) throw Error(why);
  if (layout.num_parameters() > static_cast<int>(kMaxUnknowns)) throw Error("Vulkan solver: too many unknowns");
  if (v.size() != layout.num_parameters()) throw Error("Vulkan solver inspect: v has the wrong size");
  if (!params.IsValid(&why, m.model.num_identity(), m.model.num_expression(), m.model.num_albedo())) {
    throw Error("tracker parameters: " + why);
  }
  SolverOptions o;
  o.energy = energy;
  o.render = render;
  o.max_step_halvings = 0;
  LevelInput li;
  m.prepare_level(level_frame, energy, 0, &li);
  m.current_input = &li.data;
  double unused = 0;
  const Counts counts = m.linearize(li, layout, params, o, &unused, &unused);
  const Eigen::VectorXd x = layout.Pack(params);
  VulkanLinearSystem out;
  out.gbuffer = m.renderer.read_gbuffer();
  out.vertex_state = m.renderer.read_vertex_state();
  const uint32_t n = m.n;
  const uint64_t rows = counts.rows();
  // r, J, and the pixel items.
  Analysis a = m.analyze(x, false, VulkanStrategy::kMatrixFree, o, 1);
  out.energy = a.energy;
  m.ensure_system_buffers(true, 1, true);
  m.ensure_assembled_buffers();
  std::vector<float> state_init(kStateFloats, 0.f);
  for (uint32_t i = 0; i < n; ++i) state_init[kStateX + 3 * n + i] = static_cast<float>(v[i]);
  m.state.write(state_init.data(), state_init.size() * sizeof(float));
  m.context.submit_and_wait(
      [&](VkCommandBuffer cmd) {
        gpu::CommandRecorder rec(m.context, cmd);
        Impl::record_after_everything_before(rec);
        m.record_evaluate(rec, 0, 2u);
        m.compute_barrier(rec);
        m.record_jtj(rec);
        m.record_jt(rec, 0);
        m.compute_barrier(rec);
        m.record_reduce(rec, m.jtj_partials, m.jtj_reduced, m.entry_count(), m.jtj_chunks());
        m.record_reduce(rec, m.jt_partials, m.reduced, 2 * n, m.jt_chunks());
        m.compute_barrier(rec);
        m.record_jt(rec, 1);
        m.compute_barrier(rec);
        m.record_reduce(rec, m.jt_partials, m.product, n, m.jt_chunks());
        rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                           VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_READ_BIT);
      },
      "tracker inspect");
  std::vector<float> r(rows), j(rows * n), jtj(m.entry_count()), red(2 * n), prod(n);
  std::vector<uint32_t> it(static_cast<size_t>(counts.pixels) * kPixelItemWords);
  if (rows) {
    m.residuals.read(r.data(), r.size() * 4);
    m.jacobian.read(j.data(), j.size() * 4);
  }
  if (!it.empty()) m.items.read(it.data(), it.size() * 4);
  m.jtj_reduced.read(jtj.data(), jtj.size() * 4);
  m.reduced.read(red.data(), red.size() * 4);
  m.product.read(prod.data(), prod.size() * 4);
  m.current_input = nullptr;

  // Rearrange into the CPU's order: per term, pixels in row-major order, zero rows dropped.
  std::vector<uint32_t> order(counts.pixels);
  std::iota(order.begin(), order.end(), 0u);
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return it[a * kPixelItemWords] < it[b * kPixelItemWords]; });
  const Eigen::Index total = counts.residuals();
  out.residuals.resize(total);
  out.jacobian.setZero(total, n);
  out.term_rows[0] = 0;
  out.term_rows[1] = 3 * Eigen::Index(counts.num_point);
  out.term_rows[2] = out.term_rows[1] + 2 * Eigen::Index(counts.num_plane);
  out.term_rows[3] = out.term_rows[2] + 3 * Eigen::Index(counts.num_color);
  out.term_rows[4] = out.term_rows[3] + 2 * Eigen::Index(counts.landmarks);
  out.term_rows[5] = out.term_rows[4] + counts.regularizer;
  Eigen::Index next[3] = {out.term_rows[0], out.term_rows[1], out.term_rows[2]};
  auto copy_row = [&](uint64_t src, Eigen::Index dst) {
    out.residuals[dst] = r[src];
    for (uint32_t c = 0; c < n; ++c) out.jacobian(dst, c) = j[src * n + c];
  };
  const uint32_t flag[3] = {1u, 2u, 4u};
  const int term_rows_per_pixel[3] = {3, 2, 3};
  const int first_row[3] = {0, 3, 5};
  for (int term = 0; term < 3; ++term) {
    for (uint32_t item : order) {
      if (!(it[item * kPixelItemWords + 1] & flag[term])) continue;
      for (int k = 0; k < term_rows_per_pixel[term]; ++k) copy_row(uint64_t{item} * kRowsPerPixel + first_row[term] + k, next[term]++);
    }
  }
  const uint64_t after_pixels = uint64_t{kRowsPerPixel} * counts.pixels;
  for (uint64_t k = 0; k < 2ull * counts.landmarks + counts.regularizer; ++k) copy_row(after_pixels + k, out.term_rows[3] + Eigen::Index(k));
  m.unpack_normal_equations(jtj, &out.jtj, &out.jtr);
  out.jtr_matrix_free.resize(n);
  out.normal_product.resize(n);
  for (uint32_t i = 0; i < n; ++i) {
    out.jtr_matrix_free[i] = red[i];
    out.normal_product[i] = prod[i];
  }
  return out;
}

std::vector<InputFrame> VulkanSolver::InspectPyramid(const InputFrame& frame, const PyramidOptions& options) {
  Impl& m = *impl_;
  std::vector<InputFrame> levels = PyramidLevelsWithoutPixels(frame, options);
  SolverOptions o;
  o.pyramid = options;
  o.schedule = {{static_cast<int>(levels.size()) - 1, 1, 1}};
  std::unordered_map<int, LevelInput> inputs;
  m.prepare_pyramid_on_device(frame, levels, o, inputs);
  VkDeviceSize bytes = 0;
  for (size_t l = 1; l < levels.size(); ++l) bytes += VkDeviceSize(levels[l].width()) * levels[l].height() * sizeof(glm::vec4);
  gpu::Buffer readback(m.context, std::max<VkDeviceSize>(bytes, 16), VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                       gpu::BufferDomain::Readback, "tracker pyramid readback");
  m.context.submit_and_wait(
      [&](VkCommandBuffer cmd) {
        gpu::CommandRecorder rec(m.context, cmd);
        m.record_made_pixels(rec, inputs.at(static_cast<int>(levels.size()) - 1));
        rec.memory_barrier(VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT, VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT,
                           VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_READ_BIT);
        VkDeviceSize at = 0;
        for (size_t l = 1; l < levels.size(); ++l) {
          const VkDeviceSize size = VkDeviceSize(levels[l].width()) * levels[l].height() * sizeof(glm::vec4);
          const VkBufferCopy copy{0, at, size};
          vkCmdCopyBuffer(cmd, inputs.at(static_cast<int>(l)).made.handle(), readback.handle(), 1, &copy);
          at += size;
        }
        rec.memory_barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_2_HOST_BIT,
                           VK_ACCESS_2_HOST_READ_BIT);
      },
      "tracker pyramid (inspect)");
  std::vector<glm::vec4> pixels(bytes / sizeof(glm::vec4));
  readback.read(pixels.data(), bytes);
  size_t at = 0;
  for (size_t l = 1; l < levels.size(); ++l) {
    InputFrame& f = levels[l];
    const size_t n = static_cast<size_t>(f.width()) * f.height();
    f.color.resize(3 * n);
    if (frame.has_depth()) f.depth.resize(n);
    for (size_t p = 0; p < n; ++p, ++at) {
      for (int k = 0; k < 3; ++k) f.color[3 * p + static_cast<size_t>(k)] = pixels[at][k];
      if (frame.has_depth()) f.depth[p] = pixels[at].w;
    }
  }
  return levels;
}

}  // namespace face_reenact::tracker
