#version 450
#extension GL_GOOGLE_include_directive : require
// The Gauss-Newton loop's decisions on the device: RunGaussNewton (core/tracker/src/
// gauss_newton_loop.cc) step for step, so that the Vulkan solver records a frame's whole schedule
// once and submits it once, with no read-back between iterations (vulkan_solver.cc,
// "device-driven loop"). The schedule is unrolled on the host into blocks: per level, blocks
// 0 .. iterations, each one linearisation (render + per-pixel pass + r, J) and, while the level
// goes on, the step solved there. Three stages per block, one workgroup each:
//   0 prepare  before the render: whether the block runs (its level still going on); the render's
//              inputs from x (coefficients, pose, lighting), the rotation the linearisation
//              freezes, zeroed counters, and the indirect arguments of the render and the
//              per-pixel pass (zero groups: skipped);
//   1 counts   after the per-pixel pass and the landmark pruning: the counts and residual
//              pre-scales into the level's TrackParams (the host path's write_params), a face no
//              longer in the input or J's capacity exceeded, and the arguments of the analysis
//              (with J, PCG and the trial energies when a step follows, the energy alone else);
//   2 control  after the trial energies: the energy at x closes the last step's record, then the
//              step control (the largest of dx, dx/2, ... that lowers the energy with the
//              correspondences held), the convergence test and the new record.
// State (Loop, floats; vulkan_solver.cc mirrors the indices) and the records go back to the host
// at the end of the submission. The host records a level's blocks only as far as recent frames
// needed them: a level still going at the end of its recorded blocks suspends the rest of the
// submission (prepare, at the next level's block 0, with previous_cut), and the host submits its
// remaining blocks and the levels after them; the state carries over.
layout(local_size_x = 256) in;
#include "tracker_common.glsl"
#include "common.glsl"

layout(std430, set = 0, binding = 0) buffer Params { TrackParams params; };
layout(std430, set = 0, binding = 1) buffer XVectors { float xs[]; };
layout(std430, set = 0, binding = 2) readonly buffer Base { float base[]; };  // alpha | beta | delta | ...
layout(std430, set = 0, binding = 3) readonly buffer EnergyPartials { float energy_partials[]; };
layout(std430, set = 0, binding = 4) readonly buffer PcgState { float pcg_state[]; };
layout(std430, set = 0, binding = 5) buffer Counters {
  uint pixel_count;
  uint num_point;
  uint num_plane;
  uint num_color;
  uint landmark_count;
  float landmark_weight;
  uint pad[2];
} counters;
layout(std430, set = 0, binding = 6) buffer Loop { float loop[]; };
layout(std430, set = 0, binding = 7) writeonly buffer Args { uint args[]; };
layout(std430, set = 0, binding = 8) writeonly buffer Coefficients { float coefficients[]; };  // renderer: alpha | delta | beta
layout(std430, set = 0, binding = 9) writeonly buffer Frame { FrameBlock frame; };

layout(push_constant) uniform Push {
  uint stage, level_index, block, iterations;  // block 0 .. iterations of the level
  uint level, first_level, num_trials, identity_every_block;
  uint vertex_groups, shade_groups, draw_vertices, classify_groups;  // the renderer's and the per-pixel pass's
  uint num_regularizer, capacity_rows, assembled, previous_cut;  // previous_cut: the level before was cut short
  float w_point, w_plane, w_col, w_lan;
  float inverse_unit, landmark_scale, function_tolerance;  // 1 / geometry_unit_m, reference width / width
  uint tracker_vertex_groups;  // tracker_vertices.comp's
} pc;

// Loop state indices (vulkan_solver.cc: LoopIndex).
const uint kRunning = 0u, kLevelActive = 1u, kNextSolve = 2u, kSuspended = 3u, kTermination = 4u, kTermLevel = 5u,
           kTermIteration = 6u, kAccepted = 7u, kAttempted = 8u, kRecords = 9u, kOpenRecord = 10u,
           kOverflowRows = 11u, kInitial = 12u, kFinal = 17u, kHasData = 22u, kSolved = 23u, kConvergedAt = 24u,
           kXBefore = 32u, kRecordBase = 288u, kRecordFloats = 18u;
// Terminations (vulkan_solver.cc: DeviceTermination).
const float kDone = 0.0, kNoDataAtStart = 1.0, kStepLostFace = 2.0, kNonFinite = 3.0, kOverflow = 4.0;
// Indirect argument slots, 4 uints each (vulkan_solver.cc: ArgSlot).
const uint kArgIdentity = 0u, kArgModel = 1u, kArgShade = 2u, kArgDraw = 3u, kArgClassify = 4u, kArgLandmarks = 5u,
           kArgVertices = 6u, kArgEvaluateJ = 7u, kArgEvaluateEnergy = 8u, kArgJt = 9u, kArgPcg = 10u,
           kArgTrialVertices = 11u, kArgTrialEvaluate = 12u, kArgJtj = 13u, kArgReduce = 14u;
// The PCG state (tracker_pcg.comp).
const uint kPcgIterations = 3u, kPcgInitialNorm = 4u, kPcgFinalNorm = 5u, kPcgX = 16u;

// PCG state [16 + k n ...]: dx first.
float dx_at(uint i) { return pcg_state[kPcgX + i]; }

void set_args(uint slot, uint x, uint y, uint z) {
  args[4u * slot] = x;
  args[4u * slot + 1u] = y;
  args[4u * slot + 2u] = z;
  args[4u * slot + 3u] = 0u;
}

shared float reduction[256];
float reduce_sum(float v) {
  const uint lid = gl_LocalInvocationID.x;
  reduction[lid] = v;
  barrier();
  for (uint s = 128u; s > 0u; s >>= 1) {
    if (lid < s) reduction[lid] += reduction[lid + s];
    barrier();
  }
  const float result = reduction[0];
  barrier();
  return result;
}

// A level still going where its recorded blocks ended: the rest of the submission waits for the
// host to record that level's remaining blocks (loop[kSuspended] = its index + 1).
bool suspended() { return loop[kSuspended] != 0.0; }

void prepare() {
  const uint lid = gl_LocalInvocationID.x;
  const bool was_suspended = suspended();
  const bool suspend = !was_suspended && pc.block == 0u && pc.previous_cut != 0u && loop[kLevelActive] != 0.0;
  const bool block_runs = !was_suspended && !suspend && (pc.block == 0u ? loop[kRunning] : loop[kLevelActive]) != 0.0;
  barrier();  // every invocation has read the state before it changes
  if (lid == 0u) {
    if (suspend) loop[kSuspended] = float(pc.level_index);  // the level before this one, plus one
    if (pc.block == 0u && !was_suspended && !suspend) {  // a new level: RunGaussNewton's loop over the schedule
      loop[kLevelActive] = block_runs ? 1.0 : 0.0;
      loop[kNextSolve] = pc.iterations > 0u ? 1.0 : 0.0;
    }
    const uint render = block_runs ? 1u : 0u;
    const bool identity = pc.identity_every_block != 0u || (pc.first_level != 0u && pc.block == 0u);
    set_args(kArgIdentity, block_runs && identity ? pc.vertex_groups : 0u, 1u, 1u);
    set_args(kArgModel, render * pc.vertex_groups, 1u, 1u);
    set_args(kArgShade, render * pc.shade_groups, 1u, 1u);
    args[4u * kArgDraw] = render * pc.draw_vertices;  // VkDrawIndirectCommand
    args[4u * kArgDraw + 1u] = 1u;
    args[4u * kArgDraw + 2u] = 0u;
    args[4u * kArgDraw + 3u] = 0u;
    set_args(kArgClassify, render * pc.classify_groups, 1u, 1u);
    set_args(kArgLandmarks, render, 1u, 1u);
    if (block_runs) {
      counters.pixel_count = 0u;
      counters.num_point = 0u;
      counters.num_plane = 0u;
      counters.num_color = 0u;
      counters.landmark_count = 0u;
      counters.landmark_weight = 0.0;
    }
  }
  if (!block_runs) return;
  // The render's parameters, layout.Unpack(x, base): solved coefficients from x, the rest from base.
  const uint n = params.n, model_id = params.model_id, model_alb = params.model_alb, model_exp = params.model_exp;
  for (uint q = lid; q < model_id + model_exp + model_alb; q += 256u) {
    float value;
    if (q < model_id) {
      value = q < params.k_id ? xs[params.o_id + q] : base[q];
    } else if (q < model_id + model_exp) {
      const uint e = q - model_id;
      value = e < params.k_exp ? xs[params.o_exp + e] : base[model_id + model_alb + e];
    } else {
      const uint a = q - model_id - model_exp;
      value = a < params.k_alb ? xs[params.o_alb + a] : base[model_id + a];
    }
    coefficients[q] = value;
  }
  if (lid < 27u) frame.gamma[lid] = xs[params.o_gam + lid];
  if (lid == 0u) {
    mat3 r, d[3];
    rotation_with_derivatives(vec3(xs[params.o_rot], xs[params.o_rot + 1u], xs[params.o_rot + 2u]), r, d);
    for (uint i = 0u; i < 3u; ++i) {
      frame.rotation_rows[i] = vec4(r[0][i], r[1][i], r[2][i], 0.0);  // row i (GLSL matrices are column-major)
      for (uint j = 0u; j < 3u; ++j) params.r0[3u * i + j] = r[j][i];
    }
    frame.translation = vec4(xs[params.o_t], xs[params.o_t + 1u], xs[params.o_t + 2u], 0.0);
  }
}

void counts() {
  if (gl_LocalInvocationID.x != 0u) return;
  const bool block_runs = loop[kLevelActive] != 0.0 && !suspended();
  if (!block_runs) {
    for (uint s = kArgVertices; s <= kArgReduce; ++s) set_args(s, 0u, 1u, 1u);
    return;
  }
  const uint pixels = counters.pixel_count, landmarks = counters.landmark_count, regularizer = pc.num_regularizer;
  const uint rows = system_rows(pixels, landmarks, regularizer);
  const bool has_data = pixels > 0u || landmarks > 0u;
  const bool overflow = rows > pc.capacity_rows;
  // The host path's write_params (vulkan_solver.cc) with these counts.
  params.num_pixels = pixels;
  params.num_landmarks = landmarks;
  params.num_regularizer = regularizer;
  params.rows = (rows + 3u) / 4u * 4u;
  params.s_point = counters.num_point > 0u ? sqrt(pc.w_point / float(counters.num_point)) * pc.inverse_unit : 0.0;
  params.s_plane = counters.num_plane > 0u ? sqrt(pc.w_plane / float(counters.num_plane)) * pc.inverse_unit : 0.0;
  params.s_col = counters.num_color > 0u ? sqrt(pc.w_col / float(counters.num_color)) : 0.0;
  params.s_lan = landmarks > 0u && counters.landmark_weight > 0.0
                     ? sqrt(pc.w_lan / counters.landmark_weight) * pc.landmark_scale
                     : 0.0;
  if (overflow) {  // J would not fit: the host solves this frame on its own loop (and grows J)
    loop[kRunning] = 0.0;
    loop[kLevelActive] = 0.0;
    loop[kTermination] = kOverflow;
    loop[kOverflowRows] = float(rows);
    loop[kTermLevel] = float(pc.level_index);
    for (uint s = kArgVertices; s <= kArgReduce; ++s) set_args(s, 0u, 1u, 1u);
    return;
  }
  if (!has_data) {  // RunGaussNewton: no data at the level's start, or a step lost the face
    loop[kRunning] = 0.0;
    loop[kTermination] = pc.block == 0u ? kNoDataAtStart : kStepLostFace;
    loop[kTermLevel] = float(pc.level_index);
    loop[kTermIteration] = float(pc.block);
  }
  const bool solve = has_data && loop[kNextSolve] != 0.0;
  loop[kHasData] = has_data ? 1.0 : 0.0;
  loop[kSolved] = solve ? 1.0 : 0.0;
  const uint groups = (pixels + landmarks + regularizer + 63u) / 64u;  // tracker_evaluate.comp items
  const uint on = solve ? 1u : 0u;
  set_args(kArgVertices, pc.tracker_vertex_groups, 1u, 1u);
  set_args(kArgEvaluateJ, on * groups, 1u, 1u);
  set_args(kArgEvaluateEnergy, (1u - on) * groups, 1u, 1u);
  const uint matrix_free = pc.assembled == 0u ? on : 0u, assembled = pc.assembled != 0u ? on : 0u;
  set_args(kArgJt, matrix_free * ((rows + kJtChunkRows - 1u) / kJtChunkRows), 1u, 1u);
  set_args(kArgPcg, on, 1u, 1u);
  set_args(kArgTrialVertices, on * pc.tracker_vertex_groups, pc.num_trials, 1u);
  set_args(kArgTrialEvaluate, on * groups, pc.num_trials, 1u);
  set_args(kArgJtj, assembled * ((rows + kJtjChunkRows - 1u) / kJtjChunkRows), jtj_pair_groups(params.n), 1u);
  set_args(kArgReduce, assembled * ((params.n * (params.n + 1u) + 63u) / 64u), 1u, 1u);
}

// The five term energies of x slot `slot` from tracker_evaluate.comp's per-workgroup partials.
void slot_energy(uint slot, uint groups, out float e[5]) {
  for (uint t = 0u; t < 5u; ++t) {
    float s = 0.0;
    for (uint g = gl_LocalInvocationID.x; g < groups; g += 256u) s += energy_partials[(slot * groups + g) * 5u + t];
    e[t] = reduce_sum(s);
  }
}

float total(const float e[5]) { return e[0] + e[1] + e[2] + e[3] + e[4]; }

void write_energy(uint at, const float e[5]) {
  for (uint t = 0u; t < 5u; ++t) loop[at + t] = e[t];
}

void control() {
  const uint lid = gl_LocalInvocationID.x;
  if (loop[kLevelActive] == 0.0 || suspended()) return;  // uniform
  const uint n = params.n;
  const uint groups = (params.num_pixels + params.num_landmarks + params.num_regularizer + 63u) / 64u;
  float e[5];
  slot_energy(0u, groups, e);
  const bool has_data = loop[kHasData] != 0.0, solved = loop[kSolved] != 0.0;
  const int open = int(loop[kOpenRecord]);
  const float termination = loop[kTermination];
  const uint records = uint(loop[kRecords]);
  barrier();
  if (lid == 0u) {
    if (open >= 0) write_energy(kRecordBase + uint(open) * kRecordFloats + 8u, e);  // energy_after of the last step
    loop[kOpenRecord] = -1.0;
    if (pc.block == 0u && pc.first_level != 0u) write_energy(kInitial, e);
    write_energy(kFinal, e);
  }
  if (!has_data) {
    if (termination == kStepLostFace && lid < n) xs[lid] = loop[kXBefore + lid];  // a step that loses the face is not kept
    if (lid == 0u) loop[kLevelActive] = 0.0;
    return;
  }
  if (!solved) {  // the level's last linearisation
    if (lid == 0u) loop[kLevelActive] = 0.0;
    return;
  }
  // An attempted step: its record.
  const uint rec = kRecordBase + records * kRecordFloats;
  const float residuals = float(3u * counters.num_point + 2u * counters.num_plane + 3u * counters.num_color +
                                2u * params.num_landmarks + params.num_regularizer);
  const float bad = reduce_sum(lid < n && (isnan(dx_at(lid)) || isinf(dx_at(lid))) ? 1.0 : 0.0);
  if (lid == 0u) {
    loop[kAttempted] += 1.0;
    loop[kRecords] = float(records + 1u);
    loop[rec] = float(pc.level);
    loop[rec + 1u] = float(pc.block);
    loop[rec + 2u] = residuals;
    write_energy(rec + 3u, e);
    for (uint t = 0u; t < 5u; ++t) loop[rec + 8u + t] = 0.0;
    loop[rec + 13u] = pcg_state[kPcgIterations];
    const float initial_norm = pcg_state[kPcgInitialNorm];
    loop[rec + 14u] = initial_norm > 0.0 ? pcg_state[kPcgFinalNorm] / initial_norm : 0.0;
    loop[rec + 15u] = 0.0;  // step norm
    loop[rec + 16u] = 0.0;  // halvings
    loop[rec + 17u] = float(pc.level_index);
  }
  if (bad > 0.0) {  // the linear solve produced a non-finite step
    if (lid == 0u) {
      loop[kTermination] = kNonFinite;
      loop[kTermLevel] = float(pc.level_index);
      loop[kTermIteration] = float(pc.block);
      loop[kRunning] = 0.0;
      loop[kLevelActive] = 0.0;
    }
    return;
  }
  // The largest step dx, dx/2, ... whose energy (correspondences held) is not above the start's.
  const float before = total(e);
  int accepted = -1;
  float after = 0.0;
  for (uint h = 0u; h < pc.num_trials && accepted < 0; ++h) {
    float eh[5];
    slot_energy(1u + h, groups, eh);
    const float trial = total(eh);
    if ((!isnan(trial) && !isinf(trial) && trial <= before) || pc.num_trials == 1u) {
      accepted = int(h);
      after = trial;
    }
  }
  if (accepted < 0) {  // converged on this level: no step along the direction lowered the energy
    if (lid == 0u) {
      write_energy(rec + 8u, e);
      loop[rec + 16u] = float(pc.num_trials - 1u);
      loop[kConvergedAt + pc.level_index] = float(pc.block);
      loop[kLevelActive] = 0.0;
    }
    return;
  }
  const uint from = (1u + uint(accepted)) * n;
  const float x_old = lid < n ? xs[lid] : 0.0, x_new = lid < n ? xs[from + lid] : 0.0;
  const float step_norm = sqrt(reduce_sum((x_new - x_old) * (x_new - x_old)));
  if (lid < n) {
    loop[kXBefore + lid] = x_old;
    xs[lid] = x_new;
  }
  if (lid == 0u) {
    const bool converged = before - after <= pc.function_tolerance * before;
    loop[kAccepted] += 1.0;
    loop[rec + 15u] = step_norm;
    loop[rec + 16u] = float(accepted);
    loop[kOpenRecord] = float(records);  // its energy_after comes from the next linearisation
    loop[kNextSolve] = !converged && pc.block + 1u < pc.iterations ? 1.0 : 0.0;
  }
}

void main() {
  if (pc.stage == 0u) {
    prepare();
  } else if (pc.stage == 1u) {
    counts();
  } else {
    control();
  }
}
