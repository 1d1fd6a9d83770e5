// `face-reenact keygen | send | receive`: the expression stream over authenticated UDP
// (docs/stream-protocol.md).
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <ctime>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "command_registry.h"
#include "face_reenact/common/error.h"
#include "face_reenact/common/paths.h"
#include "face_reenact/live/input_spec.h"
#include "face_reenact/live/tracked_expression_source.h"
#include "face_reenact/model/model_file.h"
#include "face_reenact/model/face_model.h"
#include "face_reenact/stream/protocol.h"
#include "face_reenact/stream/receiver.h"
#include "face_reenact/stream/sender.h"
#include "face_reenact/stream/shutdown_signals.h"
#include "face_reenact/stream/stream_key.h"
#include "face_reenact/tracker/solver_choice.h"

namespace face_reenact::cli {
namespace {

using namespace std::chrono_literals;

const char* signal_name(int sig) { return sig == SIGINT ? "SIGINT" : sig == SIGTERM ? "SIGTERM" : "signal"; }

// ---------------------------------------------------------------------------------------------
struct KeygenArgs {
  std::string out;
  bool force = false;
};

void run_keygen(const KeygenArgs& a) {
  const stream::StreamKey key = stream::StreamKey::generate();
  stream::write_key_file(a.out, key, stream::KeyFileOptions{a.force});
  std::printf("wrote a new stream key to %s (mode 0600, fingerprint %s)\n", a.out.c_str(), key.fingerprint().c_str());
  std::printf("copy it to the other machine over a secure channel (e.g. scp) and keep it private\n");
}

// ---------------------------------------------------------------------------------------------
struct SendArgs {
  std::string to, key, replay, input, model;
  std::string solver = "auto";  // --input: the tracker's solver
  int calibration_frames = -1;
  bool no_pose = false;
  int livelink_port = -1;
  uint32_t stream_id = 1;
  double rate = 0;
  bool loop = false;
  bool status = false;
  uint64_t count = 0;
  int ttl = 1;
  bool no_multicast_loop = false;
  std::string multicast_if;
};

void print_send_status(const stream::ExpressionSender& sender, const stream::ExpressionFrameSource& source,
                       double rate, const char* prefix) {
  const auto& s = sender.statistics();
  std::fprintf(stderr, "send: %ssent %llu (%.1f/s), send errors %llu, input errors %llu%s%s\n", prefix,
               static_cast<unsigned long long>(s.sent), rate, static_cast<unsigned long long>(s.send_errors),
               static_cast<unsigned long long>(source.input_errors()),
               s.last_error.empty() ? "" : ", last send error: ", s.last_error.c_str());
  if (const auto* tracked = dynamic_cast<const live::TrackedExpressionSource*>(&source)) {
    const auto& t = tracked->statistics();
    std::fprintf(stderr, "send:   tracked %lld frames (%.0f ms each), %lld while calibrating, %lld without a fit; last: %s\n",
                 static_cast<long long>(t.frames_tracked), t.tracking_ms_mean,
                 static_cast<long long>(t.frames_calibrating), static_cast<long long>(t.frames_without_fit),
                 t.last_status.c_str());
  }
  std::fflush(stderr);
}

// `send --input`: the source actor tracked live (camera / OpenNI device / recording).
std::unique_ptr<stream::ExpressionFrameSource> make_tracked_source(const SendArgs& a) {
  live::TrackedSourceOptions o;
  o.grabber.input = live::parse_target_spec(a.input, "--input");
  o.grabber.loop = a.loop;
  if (a.calibration_frames >= 0) o.tracker.calibration_frames = a.calibration_frames;
  // A camera keeps delivering while the calibration solves (seconds): the solve runs on its own
  // thread and the newest frames are tracked as soon as it is done. A recording is read frame by
  // frame, so there the calibration stays in line and the result does not depend on timing.
  o.tracker.background_calibration = o.grabber.input.kind != live::InputKind::kRecording;
  o.input.landmark_source = tracker::LandmarkSourceChoice::kDetector;
  o.send_pose = !a.no_pose;
  if (!tracker::parse_solver_backend(a.solver, &o.tracker.solver)) throw Error("send: --solver must be auto, cpu or vulkan");
  live::CheckRecordingOpens(o.grabber.input);  // before the models: a typo is reported at once
  const FaceModel model = load_face_model(resolve_model_path(a.model));
  return std::make_unique<live::TrackedExpressionSource>(model, o);
}

void run_send(const SendArgs& a) {
  const int sources = int(!a.replay.empty()) + int(a.livelink_port >= 0) + int(!a.input.empty());
  if (sources != 1)
    throw Error("send: give exactly one frame source: --input CAMERA|RECORDING, --replay PARAMS.jsonl or --livelink PORT");
  if (a.livelink_port > 65535) throw Error("send: --livelink port must be 0-65535");
  if (!std::isfinite(a.rate) || a.rate < 0 || a.rate > 10000) throw Error("send: --rate must be between 0 (the file's timestamps) and 10000 Hz");
  const stream::StreamKey key = stream::load_key_file(a.key);
  const stream::UdpEndpoint to = stream::resolve_endpoint(a.to, "--to");

  std::unique_ptr<stream::ExpressionFrameSource> source;
  if (!a.input.empty()) {
    source = make_tracked_source(a);
  } else if (!a.replay.empty()) {
    stream::ReplayFileSource::Options o;
    o.rate_hz = a.rate;
    o.loop = a.loop;
    source = std::make_unique<stream::ReplayFileSource>(stream::load_parameter_file(a.replay), o, a.replay);
  } else {
    stream::ListenSpec listen;
    listen.port = static_cast<uint16_t>(a.livelink_port);
    source = std::make_unique<stream::LiveLinkSource>(listen);
  }
  stream::ExpressionSender::Options so;
  so.stream_id = a.stream_id;
  so.multicast.ttl = a.ttl;
  so.multicast.loopback = !a.no_multicast_loop;
  so.multicast.interface_address = a.multicast_if;
  stream::ExpressionSender sender(key, to, so);

  stream::ShutdownSignals signals;
  std::fprintf(stderr, "send: %s -> %s (%s), stream %u, key %s\n", source->description().c_str(), a.to.c_str(),
               to.numeric().c_str(), a.stream_id, key.fingerprint().c_str());
  const auto started = std::chrono::steady_clock::now();
  auto last_status = started;
  uint64_t sent_at_last_status = 0;
  const char* stop_reason = "end of input";
  for (;;) {
    if (int sig = signals.wait(0ms)) {
      stop_reason = signal_name(sig);
      break;
    }
    stream::ExpressionFrame frame;
    const auto st = source->next(&frame, 50ms);
    if (st == stream::ExpressionFrameSource::Status::kEnd) break;
    if (st == stream::ExpressionFrameSource::Status::kFrame) {
      sender.send(frame);
      if (a.count > 0 && sender.statistics().sent + sender.statistics().send_errors >= a.count) {
        stop_reason = "--count reached";
        break;
      }
    }
    const auto now = std::chrono::steady_clock::now();
    if (a.status && now - last_status >= 1s) {
      const double dt = std::chrono::duration<double>(now - last_status).count();
      print_send_status(sender, *source, double(sender.statistics().sent - sent_at_last_status) / dt, "");
      last_status = now;
      sent_at_last_status = sender.statistics().sent;
    }
  }
  std::fprintf(stderr, "send: stopped (%s)\n", stop_reason);
  // The total's rate is the mean over the run (it printed 0.0/s).
  const double run_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  print_send_status(sender, *source, run_s > 0 ? double(sender.statistics().sent) / run_s : 0.0, "total: ");
  if (source->input_errors() > 0)
    std::fprintf(stderr, "send: last input error: %s\n", source->last_input_error().c_str());
}

// ---------------------------------------------------------------------------------------------
struct ReceiveArgs {
  std::string listen, key, multicast_if;
  std::vector<uint32_t> streams;
  uint64_t count = 0;
  double timeout_s = 0;
  bool json = false;
};

nlohmann::json statistics_json(const stream::ReceiverStatistics& s) {
  nlohmann::json by_reason = nlohmann::json::object();
  for (int i = 1; i < stream::kNumDatagramErrors; ++i)
    by_reason[stream::datagram_error_name(static_cast<stream::DatagramError>(i))] = s.rejected_by_reason[i];
  nlohmann::json j = {{"type", "statistics"},          {"received", s.received},
                      {"applied", s.applied},          {"rejected", s.rejected_total()},
                      {"rejected_by_reason", by_reason}, {"lost", s.lost},
                      {"reordered", s.reordered},      {"late", s.late},
                      {"standby", s.standby},          {"sequence_jumps", s.sequence_jumps},
                      {"stream_switches", s.stream_switches}, {"kernel_drops", s.kernel_drops},
                      {"rate_hz", s.rate_hz},          {"latency_ms", s.latency_ms},
                      {"latency_min_ms", s.latency_min_ms}, {"latency_jitter_ms", s.latency_jitter_ms}};
  if (s.has_active_stream) j["active_stream"] = s.active_stream;
  return j;
}

std::string frame_line(const stream::AppliedDatagram& d, bool json) {
  const stream::ExpressionFrame& f = d.frame;
  const double latency_ms = (double(d.receive_time_us) - double(f.capture_time_us)) / 1000.0;
  if (json) {
    nlohmann::json j = {{"type", "frame"},
                        {"stream", d.header.stream_id},
                        {"seq", d.header.sequence},
                        {"capture_time_us", f.capture_time_us},
                        {"receive_time_us", d.receive_time_us},
                        {"latency_ms", latency_ms},
                        {"neutral_subtracted", f.neutral_subtracted},
                        {"expression", f.expression}};
    if (!f.neutral_subtracted) j["neutral"] = f.neutral;
    if (f.has_rotation) j["rotation"] = f.rotation;
    if (f.has_translation) j["translation"] = f.translation;
    return j.dump();
  }
  // Human form: the three strongest coefficients of the relative expression.
  const auto rel = f.relative_expression();
  int top[3] = {-1, -1, -1};
  for (int i = 0; i < stream::kNumCoefficients; ++i) {
    for (int k = 0; k < 3; ++k) {
      if (top[k] < 0 || std::fabs(rel[i]) > std::fabs(rel[top[k]])) {
        for (int m = 2; m > k; --m) top[m] = top[m - 1];
        top[k] = i;
        break;
      }
    }
  }
  char buf[512];
  const auto& names = arkit_blendshape_names();
  std::snprintf(buf, sizeof(buf), "stream %u seq %llu: %s %.3f, %s %.3f, %s %.3f%s (latency %.2f ms)",
                d.header.stream_id, static_cast<unsigned long long>(d.header.sequence), names[top[0]], rel[top[0]],
                names[top[1]], rel[top[1]], names[top[2]], rel[top[2]], f.has_rotation ? ", head pose" : "",
                latency_ms);
  return buf;
}

void run_receive(const ReceiveArgs& a) {
  if (!std::isfinite(a.timeout_s) || a.timeout_s < 0) throw Error("receive: --timeout must be >= 0 seconds");
  const stream::StreamKey key = stream::load_key_file(a.key);
  stream::ExpressionReceiver::Options o;
  o.listen = stream::parse_listen_spec(a.listen, "--listen");
  o.multicast_interface = a.multicast_if;
  o.stream.allowed_streams = a.streams;

  std::atomic<uint64_t> printed{0};
  std::mutex out_mu;
  o.stream.on_applied = [&](const stream::AppliedDatagram& d) {
    if (a.count > 0 && printed.load() >= a.count) return;
    const std::string line = frame_line(d, a.json);
    std::lock_guard<std::mutex> lock(out_mu);
    std::fwrite(line.data(), 1, line.size(), stdout);
    std::fputc('\n', stdout);
    std::fflush(stdout);
    printed.fetch_add(1);
  };

  // Before the receiver thread starts, so that thread inherits the blocked signals.
  stream::ShutdownSignals signals;
  stream::ExpressionReceiver receiver(key, std::move(o));
  std::fprintf(stderr, "receive: listening on %s, UDP port %u, key %s%s\n", a.listen.c_str(), receiver.port(),
               key.fingerprint().c_str(),
               a.streams.empty() ? ", locking onto the first authenticated stream" : "");
  std::fflush(stderr);
  const auto start = std::chrono::steady_clock::now();
  bool timed_out = false;
  std::string thread_error;
  for (;;) {
    if (signals.wait(50ms)) break;
    if (a.count > 0 && printed.load() >= a.count) break;
    if (a.timeout_s > 0 && std::chrono::steady_clock::now() - start >= std::chrono::duration<double>(a.timeout_s)) {
      timed_out = true;
      break;
    }
    thread_error = receiver.thread_error();
    if (!thread_error.empty()) break;
  }
  receiver.stop();
  const stream::ReceiverStatistics s = receiver.statistics();
  {
    std::lock_guard<std::mutex> lock(out_mu);
    if (a.json) {
      const std::string line = statistics_json(s).dump();
      std::fwrite(line.data(), 1, line.size(), stdout);
      std::fputc('\n', stdout);
    } else {
      std::printf("%s, latency %.2f ms\n", s.Counts().c_str(), s.latency_ms);
      for (int i = 1; i < stream::kNumDatagramErrors; ++i)
        if (s.rejected_by_reason[i] > 0)
          std::printf("  rejected %s: %llu\n", stream::datagram_error_name(static_cast<stream::DatagramError>(i)),
                      static_cast<unsigned long long>(s.rejected_by_reason[i]));
    }
    std::fflush(stdout);
  }
  if (!thread_error.empty()) throw Error("receive: " + thread_error);
  if (timed_out && a.count > 0 && printed.load() < a.count)
    throw Error("receive: timed out after " + std::to_string(a.timeout_s) + " s with " +
                std::to_string(printed.load()) + " of " + std::to_string(a.count) + " datagrams applied");
}


// ---------------------------------------------------------------------------------------------
struct BenchStreamArgs {
  double rate = 10000;
  double seconds = 2;
  bool json = false;
};

// `face-reenact bench stream`: the per-datagram cost of the protocol and whether a real
// receiver thread on 127.0.0.1 keeps up with a paced sender at --rate datagrams per second.
void run_bench_stream(const BenchStreamArgs& a) {
  if (!std::isfinite(a.rate) || a.rate <= 0 || a.rate > 1e6) throw Error("bench stream: --rate must be in (0, 1e6]");
  if (!std::isfinite(a.seconds) || a.seconds <= 0 || a.seconds > 600) throw Error("bench stream: --seconds must be in (0, 600]");
  const stream::StreamKey key = stream::StreamKey::generate();
  stream::ExpressionFrame frame;
  for (int i = 0; i < stream::kNumCoefficients; ++i) frame.expression[i] = 0.01f * float(i);
  frame.has_rotation = true;
  frame.rotation = {0.1f, 0.f, 0.f};

  // Encode and verify+decrypt+apply costs over a batch of distinct datagrams, in this thread's
  // CPU time (wall time on a busy machine would include other processes).
  constexpr int kN = 20000;
  std::vector<std::array<uint8_t, stream::kMaxDatagramSize>> buf(kN);
  std::vector<size_t> len(kN);
  auto cpu_us = [] {
    timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) * 1e6 + double(ts.tv_nsec) / 1e3;
  };
  const double t0 = cpu_us();
  for (int i = 0; i < kN; ++i) len[i] = stream::encode_datagram(key, 1, uint64_t(i) + 1, frame, buf[i]);
  const double t1 = cpu_us();
  const auto now = stream::SteadyClock::now();
  {
    stream::ExpressionStreamState state(key, {});
    for (int i = 0; i < kN; ++i) state.process(std::span<const uint8_t>(buf[i].data(), len[i]), now, 0);
    if (state.statistics(now).applied != kN) throw Error("bench stream: datagrams failed to verify");
  }
  const double t2 = cpu_us();
  for (int i = 0; i < kN; ++i) buf[i][len[i] - 1] ^= 1;  // forge the tags
  const double t3 = cpu_us();
  {
    stream::ExpressionStreamState state(key, {});  // fresh: no replay shortcut, every tag is checked
    for (int i = 0; i < kN; ++i) state.process(std::span<const uint8_t>(buf[i].data(), len[i]), now, 0);
    if (state.statistics(now).rejected(stream::DatagramError::kAuthFailed) != kN)
      throw Error("bench stream: forged datagrams were not all rejected as forged");
  }
  const double t4 = cpu_us();
  const double encode_us = (t1 - t0) / kN, open_us = (t2 - t1) / kN, forged_us = (t4 - t3) / kN;

  // A real receiver thread fed at the requested rate with absolute deadlines.
  stream::ExpressionReceiver::Options o;
  o.listen.address = "127.0.0.1";
  stream::ExpressionReceiver rx(key, o);
  stream::ExpressionSender tx(key, stream::resolve_endpoint("127.0.0.1:" + std::to_string(rx.port()), "bench"), {});
  const auto start = std::chrono::steady_clock::now();
  const auto period = std::chrono::duration<double>(1.0 / a.rate);
  const uint64_t total = static_cast<uint64_t>(std::llround(a.rate * a.seconds));
  for (uint64_t n = 0; n < total; ++n) {
    const auto due = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(period * double(n));
    if (due > std::chrono::steady_clock::now()) std::this_thread::sleep_until(due);
    frame.capture_time_us = stream::realtime_now_us();
    tx.send(frame);
  }
  const double send_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const auto wait_end = std::chrono::steady_clock::now() + 2s;
  while (std::chrono::steady_clock::now() < wait_end) {
    const auto s = rx.statistics();
    if (s.received + s.kernel_drops >= total) break;
    std::this_thread::sleep_for(5ms);
  }
  const stream::ReceiverStatistics s = rx.statistics();
  const bool kept_up = s.applied == total && s.kernel_drops == 0 && s.lost == 0;
  const double offered = double(total) / send_seconds;
  if (a.json) {
    const nlohmann::json j = {{"encode_us", encode_us},          {"verify_decrypt_apply_us", open_us},
                              {"reject_forged_us", forged_us},   {"offered_per_s", offered},
                              {"sent", total},                   {"send_errors", tx.statistics().send_errors},
                              {"applied", s.applied},            {"kernel_drops", s.kernel_drops},
                              {"lost", s.lost},                  {"latency_ms", s.latency_ms},
                              {"kept_up", kept_up}};
    std::printf("%s\n", j.dump().c_str());
  } else {
    std::printf("per datagram (CPU time): encode %.2f us, verify+decrypt+apply %.2f us, reject forged %.2f us\n", encode_us,
                open_us, forged_us);
    std::printf("loopback receiver: offered %.0f/s for %.2f s: sent %llu, applied %llu, kernel drops %llu, lost %llu, "
                "latency %.3f ms -> %s\n",
                offered, send_seconds, static_cast<unsigned long long>(total),
                static_cast<unsigned long long>(s.applied), static_cast<unsigned long long>(s.kernel_drops),
                static_cast<unsigned long long>(s.lost), s.latency_ms, kept_up ? "kept up" : "FELL BEHIND");
  }
}
// ---------------------------------------------------------------------------------------------
void add_stream_commands(CLI::App& app) {
  {
    auto args = std::make_shared<KeygenArgs>();
    CLI::App* c = app.add_subcommand("keygen", "Write a new random pre-shared key for the expression stream");
    c->add_option("--out", args->out, "Key file to create (mode 0600; never overwritten without --force)")->required();
    c->add_flag("--force", args->force, "Replace an existing key file");
    c->callback([args] { run_keygen(*args); });
  }
  {
    auto args = std::make_shared<SendArgs>();
    CLI::App* c = app.add_subcommand("send", "Stream expression parameters to a target over authenticated UDP");
    c->add_option("--to", args->to, "Destination HOST:PORT (unicast, or an IPv4 multicast group)")->required();
    c->add_option("--key", args->key, "Pre-shared key file (face-reenact keygen)")->required();
    auto* replay = c->add_option("--replay", args->replay, "Parameter file to replay (JSON Lines, docs/stream-protocol.md)");
    auto* livelink = c->add_option("--livelink", args->livelink_port, "Relay Live Link Face (iPhone) packets received on this UDP port");
    replay->excludes(livelink);
    auto* input = c->add_option("--input", args->input,
                                "Track the source actor live: a camera (/dev/videoN), openni[:URI], or a recording/video");
    input->excludes(replay)->excludes(livelink);
    c->add_option("--model", args->model, "Face model file for --input (default: the built one)");
    c->add_option("--calibration-frames", args->calibration_frames,
                  "--input: frames to calibrate the actor over before sending (keep a neutral face)");
    c->add_flag("--no-pose", args->no_pose, "--input: do not send the head pose");
    c->add_option("--solver", args->solver,
                  "--input: the tracker's solver: auto (the Vulkan solver on a GPU, the CPU solver where Vulkan runs on the "
                  "CPU), cpu or vulkan")
        ->capture_default_str();
    c->add_option("--stream", args->stream_id, "Stream id (u32) the receivers allow")->capture_default_str();
    c->add_option("--rate", args->rate, "Replay rate in Hz (default: the file's timestamps, else 30)");
    c->add_flag("--loop", args->loop, "Replay the file (or the --input recording) in a loop");
    c->add_flag("--status", args->status, "Print a status line per second to stderr");
    c->add_option("--count", args->count, "Stop after sending this many datagrams");
    c->add_option("--ttl", args->ttl, "Multicast TTL (0: this host, 1: local network)")->capture_default_str();
    c->add_flag("--no-multicast-loop", args->no_multicast_loop, "Do not deliver multicast to receivers on this host");
    c->add_option("--multicast-if", args->multicast_if, "IPv4 address of the interface to send multicast on");
    c->callback([args] { run_send(*args); });
  }
  {
    auto args = std::make_shared<ReceiveArgs>();
    CLI::App* c = app.add_subcommand("receive", "Receive and print an expression stream");
    c->add_option("--listen", args->listen, "PORT, ADDR:PORT, or GROUP:PORT (IPv4 multicast)")->required();
    c->add_option("--key", args->key, "Pre-shared key file (face-reenact keygen)")->required();
    c->add_option("--stream", args->streams,
                  "Allowed stream id (repeatable; default: lock onto the first authenticated stream)");
    c->add_option("--count", args->count, "Exit after this many datagrams applied");
    c->add_option("--timeout", args->timeout_s, "Exit after this many seconds");
    c->add_flag("--json", args->json, "One JSON line per applied datagram, then a statistics line");
    c->add_option("--multicast-if", args->multicast_if, "IPv4 address of the interface to join the group on");
    c->callback([args] { run_receive(*args); });
  }
  {
    auto args = std::make_shared<BenchStreamArgs>();
    CLI::App* bench = get_or_add_subcommand(app, "bench", "Measure the cost of pipeline stages");
    CLI::App* c = bench->add_subcommand("stream", "Expression stream: per-datagram cost and loopback receiver rate");
    c->add_option("--rate", args->rate, "Datagrams per second offered to the receiver")->capture_default_str();
    c->add_option("--seconds", args->seconds, "How long to send")->capture_default_str();
    c->add_flag("--json", args->json, "Machine-readable output");
    c->callback([args] { run_bench_stream(*args); });
  }
}

}  // namespace

FR_REGISTER_COMMANDS(stream, add_stream_commands);

}  // namespace face_reenact::cli
