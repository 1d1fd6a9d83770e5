// Benchmarks of the expression stream (run: build/bin/stream_benchmark).
//  - per-datagram cost of encoding, and of verifying+decrypting+applying on the receiver;
//  - cost of rejecting forged / unknown-stream datagrams (what a flood costs the receiver);
//  - a real ExpressionReceiver on 127.0.0.1 fed at a paced rate (10k, 20k, 50k datagrams/s)
//    and unpaced, reporting whether it kept up (no kernel drops, nothing lost).
#include <benchmark/benchmark.h>
#include <time.h>

#include <thread>

#include "face_reenact/stream/receiver.h"
#include "face_reenact/stream/sender.h"
#include "stream_test_util.h"

namespace face_reenact::stream {
namespace {

using testing::encode;
using testing::make_frame;
using testing::test_key;

void BM_EncodeDatagram(benchmark::State& state) {
  const StreamKey key = test_key();
  const ExpressionFrame f = make_frame(1, state.range(0) != 0, state.range(0) != 0);
  std::array<uint8_t, kMaxDatagramSize> buf;
  uint64_t seq = 1;
  for (auto _ : state) benchmark::DoNotOptimize(encode_datagram(key, 1, seq++, f, buf));
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_EncodeDatagram)->Arg(0)->Arg(1)->ArgName("neutral_and_pose");

// Receiver work per valid datagram: header checks, replay window, AEAD verify+decrypt, value
// validation, latest-wins bookkeeping.
void BM_VerifyDecryptApply(benchmark::State& state) {
  const StreamKey key = test_key();
  const bool big = state.range(0) != 0;
  constexpr size_t kN = 8192;
  std::vector<std::vector<uint8_t>> d;
  for (size_t i = 0; i < kN; ++i) d.push_back(encode(key, 1, i + 1, make_frame(static_cast<uint32_t>(i), big, big)));
  size_t i = 0;
  auto st = std::make_unique<ExpressionStreamState>(key, StreamStateOptions{});
  const auto t = SteadyClock::now();
  for (auto _ : state) {
    if (i == kN) {
      state.PauseTiming();
      st = std::make_unique<ExpressionStreamState>(key, StreamStateOptions{});
      i = 0;
      state.ResumeTiming();
    }
    benchmark::DoNotOptimize(st->process(d[i++], t, 0));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_VerifyDecryptApply)->Arg(0)->Arg(1)->ArgName("neutral_and_pose");

void BM_RejectForged(benchmark::State& state) {
  const StreamKey key = test_key();
  auto d = encode(key, 1, 1, make_frame(1));
  d.back() ^= 1;
  ExpressionStreamState st(key, StreamStateOptions{});
  const auto t = SteadyClock::now();
  for (auto _ : state) benchmark::DoNotOptimize(st.process(d, t, 0));
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_RejectForged);

void BM_RejectUnknownStream(benchmark::State& state) {
  const StreamKey key = test_key();
  const auto d = encode(key, 2, 1, make_frame(1));
  StreamStateOptions o;
  o.allowed_streams = {1};
  ExpressionStreamState st(key, o);
  const auto t = SteadyClock::now();
  for (auto _ : state) benchmark::DoNotOptimize(st.process(d, t, 0));
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_RejectUnknownStream);

void BM_Sample(benchmark::State& state) {
  const StreamKey key = test_key();
  ExpressionStreamState st(key, StreamStateOptions{});
  st.process(encode(key, 1, 1, make_frame(1)), SteadyClock::now(), 0);
  for (auto _ : state) benchmark::DoNotOptimize(st.sample(SteadyClock::now()));
}
BENCHMARK(BM_Sample);

// A real receiver thread on loopback, fed by a sender on this thread for one second at
// range(0) datagrams/s (0: as fast as the sender can go). Counters: the offered and delivered
// rates, kernel drops (receiver fell behind), lost (sequence gaps).
void BM_LoopbackReceiver(benchmark::State& state) {
  const StreamKey key = test_key();
  const double rate = static_cast<double>(state.range(0));
  double offered = 0, applied_rate = 0, drops = 0, lost = 0;
  for (auto _ : state) {
    ExpressionReceiver::Options o;
    o.listen.address = "127.0.0.1";
    ExpressionReceiver rx(key, o);
    ExpressionSender tx(key, resolve_endpoint("127.0.0.1:" + std::to_string(rx.port()), "bench"), {});
    // Pre-encoded frames would hide the sender's cost; encode as a real sender does.
    const ExpressionFrame f = make_frame(1);
    const auto start = std::chrono::steady_clock::now();
    const auto end = start + std::chrono::seconds(1);
    uint64_t n = 0;
    timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    const long period_ns = rate > 0 ? static_cast<long>(1e9 / rate) : 0;
    while (std::chrono::steady_clock::now() < end) {
      if (rate > 0) {
        // Absolute deadlines in small bursts of 10 (sleep granularity is ~50-100 us).
        next.tv_nsec += period_ns * 10;
        while (next.tv_nsec >= 1'000'000'000) {
          next.tv_nsec -= 1'000'000'000;
          ++next.tv_sec;
        }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, nullptr);
        for (int k = 0; k < 10; ++k, ++n) tx.send(f);
      } else {
        tx.send(f);
        ++n;
      }
    }
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    testing::wait_for([&] { return rx.statistics().received + rx.statistics().kernel_drops >= n; },
                      std::chrono::seconds(3));
    const ReceiverStatistics s = rx.statistics();
    offered = double(n) / seconds;
    applied_rate = double(s.applied) / seconds;
    drops = double(s.kernel_drops);
    lost = double(s.lost);
    if (tx.statistics().send_errors > 0) state.SkipWithError("sender reported errors");
  }
  state.counters["offered_per_s"] = offered;
  state.counters["applied_per_s"] = applied_rate;
  state.counters["kernel_drops"] = drops;
  state.counters["lost"] = lost;
}
BENCHMARK(BM_LoopbackReceiver)->Arg(10000)->Arg(20000)->Arg(50000)->Arg(0)->Iterations(1)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace face_reenact::stream

BENCHMARK_MAIN();
