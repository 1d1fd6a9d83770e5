// End-to-end: the real `face-reenact keygen/send/receive` processes (FR_CLI) on 127.0.0.1.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "face_reenact/stream/livelink.h"
#include "face_reenact/stream/sender.h"
#include "face_reenact/stream/udp.h"
#include "stream_test_util.h"
#include "support/child_process.h"
#include "support/temp_dir.h"

namespace face_reenact::stream {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

using Process = face_reenact::testing::ChildProcess;

class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const char* cli = std::getenv("FR_CLI");
    if (!cli || !fs::exists(cli)) GTEST_SKIP() << "FR_CLI is not set to the face-reenact executable";
    cli_ = cli;
  }
  std::string path(const std::string& n) const { return (dir_ / n).string(); }
  std::unique_ptr<Process> start(std::vector<std::string> args, const std::string& name) {
    args.insert(args.begin(), cli_);
    auto p = std::make_unique<Process>(args, dir_, name);
    EXPECT_TRUE(p->started());
    return p;
  }
  int run(std::vector<std::string> args, std::string* out = nullptr, std::string* err = nullptr) {
    auto p = start(std::move(args), "run" + std::to_string(runs_++));
    const int rc = p->wait();
    if (out) *out = p->out();
    if (err) *err = p->err();
    return rc;
  }
  std::string keygen(const std::string& name = "key") {
    EXPECT_EQ(run({"keygen", "--out", path(name)}), 0);
    return path(name);
  }
  static uint16_t free_port() {
    ListenSpec l;
    l.address = "127.0.0.1";
    return UdpSocket::open_receiver(l, "", 0).local_port();
  }
  static bool wait_for_text(const Process& p, const std::string& text, std::chrono::milliseconds limit = 10s) {
    return testing::wait_for([&] { return p.err().find(text) != std::string::npos; }, limit);
  }
  std::string cli_;
  const face_reenact::testing::TempDir tmp_{"fr-cli"};
  const fs::path dir_ = tmp_.path();
  int runs_ = 0;
};

std::vector<nlohmann::json> json_lines(const std::string& text) {
  std::vector<nlohmann::json> v;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line))
    if (!line.empty()) v.push_back(nlohmann::json::parse(line));
  return v;
}

TEST_F(CliTest, KeygenWritesAPrivateKeyAndNeverOverwrites) {
  std::string out, err;
  ASSERT_EQ(run({"keygen", "--out", path("k")}, &out), 0);
  EXPECT_NE(out.find("fingerprint"), std::string::npos);
  struct stat st;
  ASSERT_EQ(::stat(path("k").c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  const std::string first = read_text(path("k"));
  EXPECT_EQ(run({"keygen", "--out", path("k")}, &out, &err), 1);
  EXPECT_NE(err.find("already exists"), std::string::npos) << err;
  EXPECT_EQ(read_text(path("k")), first);
  EXPECT_EQ(run({"keygen", "--out", path("k"), "--force"}), 0);
  EXPECT_NE(read_text(path("k")), first);
}

TEST_F(CliTest, SendReplayIsReceivedAsJson) {
  const std::string key = keygen();
  // 40 frames at 200 Hz with neutral and pose on some lines.
  std::vector<ParameterFrame> frames;
  {
    std::ofstream f(path("params.jsonl"));
    for (int i = 0; i < 40; ++i) {
      ParameterFrame pf;
      pf.frame = testing::make_frame(static_cast<uint32_t>(i), i % 4 == 0, i % 5 == 0);
      pf.has_timestamp = true;
      pf.timestamp_us = 1'000'000 + i * 5000;
      pf.frame_number = i;
      frames.push_back(pf);
      f << format_parameter_line(pf) << "\n";
    }
  }
  const uint16_t port = free_port();
  auto rx = start({"receive", "--listen", "127.0.0.1:" + std::to_string(port), "--key", key, "--json", "--count",
                   "40", "--timeout", "30", "--stream", "9"},
                  "receive");
  ASSERT_TRUE(wait_for_text(*rx, "listening")) << rx->err();
  std::string send_err;
  ASSERT_EQ(run({"send", "--to", "127.0.0.1:" + std::to_string(port), "--key", key, "--replay",
                 path("params.jsonl"), "--stream", "9"},
                nullptr, &send_err),
            0)
      << send_err;
  EXPECT_NE(send_err.find("sent 40"), std::string::npos) << send_err;
  ASSERT_EQ(rx->wait(), 0) << rx->err();
  const auto lines = json_lines(rx->out());
  ASSERT_EQ(lines.size(), 41u) << rx->out();
  uint64_t prev_seq = 0;
  for (int i = 0; i < 40; ++i) {
    const auto& j = lines[i];
    ASSERT_EQ(j["type"], "frame");
    EXPECT_EQ(j["stream"], 9);
    const uint64_t seq = j["seq"];
    if (i > 0) EXPECT_EQ(seq, prev_seq + 1);
    prev_seq = seq;
    const auto& want = frames[i].frame;
    ASSERT_EQ(j["expression"].size(), 52u);
    for (int k = 0; k < 52; ++k) EXPECT_EQ(j["expression"][k].get<float>(), want.expression[k]);
    EXPECT_EQ(j["neutral_subtracted"].get<bool>(), want.neutral_subtracted);
    if (!want.neutral_subtracted) EXPECT_EQ(j["neutral"][3].get<float>(), want.neutral[3]);
    EXPECT_EQ(j.contains("rotation"), want.has_rotation);
    if (want.has_translation) EXPECT_EQ(j["translation"][2].get<float>(), want.translation[2]);
    EXPECT_GT(j["capture_time_us"].get<uint64_t>(), 0u);
  }
  const auto& s = lines.back();
  ASSERT_EQ(s["type"], "statistics");
  EXPECT_EQ(s["received"], 40);
  EXPECT_EQ(s["applied"], 40);
  EXPECT_EQ(s["rejected"], 0);
  EXPECT_EQ(s["lost"], 0);
  EXPECT_EQ(s["reordered"], 0);
  EXPECT_EQ(s["active_stream"], 9);
  EXPECT_TRUE(s["rejected_by_reason"].contains("auth_failed"));
}

TEST_F(CliTest, WrongKeyAndUnknownStreamAreRejectedByReason) {
  const std::string key = keygen("a"), other = keygen("b");
  std::string e = "[0.5";
  for (int k = 1; k < 52; ++k) e += ",0.25";
  e += "]";
  {
    std::ofstream f(path("p.jsonl"));
    for (int i = 0; i < 10; ++i) f << "{\"expression\": " << e << "}\n";
    std::ofstream(path("one.jsonl")) << "{\"expression\": " << e << "}\n";
  }
  const uint16_t port = free_port();
  // The receiver exits after the first applied datagram; datagrams on one socket are processed
  // in order, so by then it has processed all the rejected ones sent before.
  auto rx = start({"receive", "--listen", "127.0.0.1:" + std::to_string(port), "--key", key, "--json", "--timeout",
                   "60", "--count", "1", "--stream", "1"},
                  "receive");
  ASSERT_TRUE(wait_for_text(*rx, "listening"));
  const std::string to = "127.0.0.1:" + std::to_string(port);
  EXPECT_EQ(run({"send", "--to", to, "--key", other, "--replay", path("p.jsonl"), "--rate", "200"}), 0);
  EXPECT_EQ(run({"send", "--to", to, "--key", key, "--replay", path("p.jsonl"), "--rate", "200", "--stream", "2"}), 0);
  EXPECT_EQ(run({"send", "--to", to, "--key", key, "--replay", path("one.jsonl"), "--stream", "1"}), 0);
  ASSERT_EQ(rx->wait(), 0) << rx->err();
  const auto lines = json_lines(rx->out());
  ASSERT_EQ(lines.size(), 2u) << rx->out();
  EXPECT_EQ(lines[0]["type"], "frame");
  EXPECT_EQ(lines[1]["applied"], 1);
  EXPECT_EQ(lines[1]["received"], 21);
  EXPECT_EQ(lines[1]["rejected"], 20);
  EXPECT_EQ(lines[1]["rejected_by_reason"]["auth_failed"], 10);
  EXPECT_EQ(lines[1]["rejected_by_reason"]["unknown_stream"], 10);
}

TEST_F(CliTest, LiveLinkPacketsAreRelayedAsAuthenticatedStream) {
  const std::string key = keygen();
  const uint16_t port = free_port(), phone_port = free_port();
  auto rx = start({"receive", "--listen", "127.0.0.1:" + std::to_string(port), "--key", key, "--json", "--count", "3",
                   "--timeout", "30"},
                  "receive");
  auto tx = start({"send", "--to", "127.0.0.1:" + std::to_string(port), "--key", key, "--livelink",
                   std::to_string(phone_port)},
                  "send");
  ASSERT_TRUE(wait_for_text(*rx, "listening"));
  ASSERT_TRUE(wait_for_text(*tx, "Live Link Face on UDP port")) << tx->err();
  UdpSocket phone = UdpSocket::open_sender(resolve_endpoint("127.0.0.1:" + std::to_string(phone_port), "t"), {});
  LiveLinkPacket p;
  p.subject_name = "iPhone";
  for (int i = 0; i < kLiveLinkValues; ++i) p.values[i] = 0.02f * float(i % 30);
  p.values[52] = 0.3f;  // yaw only: the rotation is 0.3 rad about +y
  p.values[53] = p.values[54] = 0.f;
  ASSERT_TRUE(testing::wait_for([&] {
    phone.send(std::vector<uint8_t>{1, 2, 3});  // junk from the "phone" is counted, not relayed
    phone.send(encode_livelink_packet(p));
    std::this_thread::sleep_for(20ms);
    return rx->out().find("\"type\":\"statistics\"") != std::string::npos;
  }));
  ASSERT_EQ(rx->wait(), 0);
  tx->signal(SIGTERM);
  ASSERT_EQ(tx->wait(), 0) << tx->err();
  EXPECT_NE(tx->err().find("stopped (SIGTERM)"), std::string::npos) << tx->err();
  EXPECT_NE(tx->err().find("last input error: Live Link packet"), std::string::npos) << tx->err();
  const auto lines = json_lines(rx->out());
  ASSERT_EQ(lines.size(), 4u);
  EXPECT_EQ(lines[0]["expression"][17].get<float>(), p.values[17]);
  EXPECT_NEAR(lines[0]["rotation"][1].get<float>(), 0.3f, 1e-6);
}

TEST_F(CliTest, ServicesStopCleanlyOnSignals) {
  const std::string key = keygen();
  const uint16_t port = free_port();
  auto rx = start({"receive", "--listen", "127.0.0.1:" + std::to_string(port), "--key", key, "--json"}, "receive");
  ASSERT_TRUE(wait_for_text(*rx, "listening"));
  {
    std::ofstream f(path("p.jsonl"));
    std::string e = "[0.5";
    for (int k = 1; k < 52; ++k) e += ",0.25";
    f << "{\"expression\": " << e << "]}\n";
  }
  auto tx = start({"send", "--to", "127.0.0.1:" + std::to_string(port), "--key", key, "--replay", path("p.jsonl"),
                   "--loop", "--rate", "50", "--status"},
                  "send");
  ASSERT_TRUE(wait_for_text(*tx, "/s), send errors 0")) << tx->err();  // a per-second status line
  tx->signal(SIGINT);
  EXPECT_EQ(tx->wait(5s), 0);
  EXPECT_NE(tx->err().find("stopped (SIGINT)"), std::string::npos) << tx->err();
  rx->signal(SIGTERM);
  EXPECT_EQ(rx->wait(5s), 0);
  const auto lines = json_lines(rx->out());
  ASSERT_GE(lines.size(), 2u);
  EXPECT_EQ(lines.back()["type"], "statistics");
  EXPECT_GT(lines.back()["applied"].get<int>(), 10);
  EXPECT_EQ(lines.back()["rejected"], 0);
}

TEST_F(CliTest, BenchStreamReportsCostsAndReceiverRate) {
  std::string out, err;
  ASSERT_EQ(run({"bench", "stream", "--rate", "2000", "--seconds", "0.5", "--json"}, &out, &err), 0) << err;
  const auto lines = json_lines(out);
  ASSERT_EQ(lines.size(), 1u) << out;
  const auto& j = lines[0];
  EXPECT_EQ(j["sent"], 1000);
  EXPECT_EQ(j["send_errors"], 0);
  EXPECT_GT(j["applied"].get<int>(), 0);
  EXPECT_LE(j["applied"].get<int>() + j["kernel_drops"].get<int>(), 1000);
  EXPECT_GT(j["verify_decrypt_apply_us"].get<double>(), 0.0);
  EXPECT_GT(j["reject_forged_us"].get<double>(), 0.0);
  EXPECT_TRUE(j.contains("kept_up"));
  EXPECT_NE(run({"bench", "stream", "--rate", "0"}, nullptr, &err), 0);
  EXPECT_NE(err.find("--rate"), std::string::npos) << err;
}

TEST_F(CliTest, BadArgumentsExitNonZeroWithClearMessages) {
  const std::string key = keygen();
  {
    std::ofstream f(path("p.jsonl"));
    std::string e = "[0.5";
    for (int k = 1; k < 52; ++k) e += ",0.25";
    f << "{\"expression\": " << e << "]}\n";
  }
  std::ofstream(path("bad.jsonl")) << "{\"expression\": [1, 2]}\n";
  std::string err;
  EXPECT_EQ(run({"send", "--to", "127.0.0.1:9", "--key", key}, nullptr, &err), 1);
  EXPECT_NE(err.find("--replay PARAMS.jsonl or --livelink PORT"), std::string::npos) << err;
  EXPECT_EQ(run({"send", "--to", "no-such-host.invalid:9", "--key", key, "--replay", path("p.jsonl")}, nullptr, &err), 1);
  EXPECT_NE(err.find("cannot resolve host"), std::string::npos) << err;
  EXPECT_EQ(run({"send", "--to", "127.0.0.1", "--key", key, "--replay", path("p.jsonl")}, nullptr, &err), 1);
  EXPECT_NE(err.find("HOST:PORT"), std::string::npos) << err;
  EXPECT_EQ(run({"send", "--to", "127.0.0.1:9", "--key", key, "--replay", path("bad.jsonl")}, nullptr, &err), 1);
  EXPECT_NE(err.find("bad.jsonl:1: \"expression\" must be an array of 52 numbers"), std::string::npos) << err;
  EXPECT_EQ(run({"send", "--to", "127.0.0.1:9", "--key", path("absent"), "--replay", path("p.jsonl")}, nullptr, &err), 1);
  EXPECT_NE(err.find("cannot open key file"), std::string::npos) << err;
  ::chmod(key.c_str(), 0644);
  EXPECT_EQ(run({"send", "--to", "127.0.0.1:9", "--key", key, "--replay", path("p.jsonl")}, nullptr, &err), 1);
  EXPECT_NE(err.find("permissions 0644"), std::string::npos) << err;
  EXPECT_EQ(run({"receive", "--listen", "5000", "--key", key}, nullptr, &err), 1);
  EXPECT_NE(err.find("permissions 0644"), std::string::npos) << err;
  ::chmod(key.c_str(), 0600);
  EXPECT_NE(run({"send", "--to", "127.0.0.1:9", "--key", key, "--replay", path("p.jsonl"), "--livelink", "5"}, nullptr, &err), 0);
  EXPECT_NE(err.find("excludes"), std::string::npos) << err;
  EXPECT_EQ(run({"receive", "--listen", "not-a-port", "--key", key}, nullptr, &err), 1);
  EXPECT_NE(err.find("not a port number"), std::string::npos) << err;
  EXPECT_EQ(run({"receive", "--listen", "127.0.0.1:" + std::to_string(free_port()), "--key", key, "--count", "5",
                 "--timeout", "0.3"},
                nullptr, &err),
            1);
  EXPECT_NE(err.find("timed out"), std::string::npos) << err;
}

// `send --input RECORDING`: the source actor is tracked (dlib landmarks, calibration, tracking)
// and every trustworthy fit after calibration goes out as a datagram with the actor's neutral.
TEST_F(CliTest, SendInputTracksARecordingAndStreamsItsExpressions) {
  if (!std::getenv("FR_MODEL") || !fs::exists(std::getenv("FR_MODEL")))
    GTEST_SKIP() << "FR_MODEL is not set to a built face model (run face-reenact model build)";
  const std::string model = std::getenv("FR_MODEL");
  std::string err;
  ASSERT_EQ(run({"synth", "--seed", "31", "--frames", "6", "--size", "320x240", "--out", path("rec"), "--model", model}, nullptr, &err), 0)
      << err;
  const std::string key = keygen();
  const uint16_t port = free_port();
  auto rx = start({"receive", "--listen", "127.0.0.1:" + std::to_string(port), "--key", key, "--json", "--timeout",
                   "240"},
                  "receive");
  ASSERT_TRUE(wait_for_text(*rx, "listening")) << rx->err();
  auto tx = start({"send", "--to", "127.0.0.1:" + std::to_string(port), "--key", key, "--input", path("rec"),
                   "--calibration-frames", "2", "--model", model},
                  "send");
  ASSERT_EQ(tx->wait(240s), 0) << tx->err();
  const std::string send_err = tx->err();
  EXPECT_NE(send_err.find("tracked 6 frames"), std::string::npos) << send_err;
  rx->signal(SIGINT);
  ASSERT_EQ(rx->wait(), 0) << rx->err();
  const auto lines = json_lines(rx->out());
  ASSERT_GE(lines.size(), 4u) << "expected at least 3 frames after a 2-frame calibration\n" << send_err;
  double spread = 0;
  for (size_t i = 0; i + 1 < lines.size(); ++i) {
    const auto& j = lines[i];
    ASSERT_EQ(j["type"], "frame");
    EXPECT_FALSE(j["neutral_subtracted"].get<bool>()) << "the sender's neutral travels with each frame";
    ASSERT_EQ(j["expression"].size(), 52u);
    ASSERT_EQ(j["neutral"].size(), 52u);
    for (int k = 0; k < 52; ++k) {
      const float e = j["expression"][k].get<float>();
      EXPECT_GE(e, 0.f);
      EXPECT_LE(e, 1.f);
      spread += std::abs(e - j["neutral"][k].get<float>());
    }
    ASSERT_TRUE(j.contains("rotation") && j.contains("translation")) << j.dump();
    // The synthetic actor sits 0.5-1 m in front of the camera, facing it within ~30 degrees.
    const double z = j["translation"][2].get<double>();
    EXPECT_GT(z, 0.3);
    EXPECT_LT(z, 1.5);
    const double angle = std::hypot(j["rotation"][0].get<double>(), j["rotation"][1].get<double>(),
                                    j["rotation"][2].get<double>());
    EXPECT_LT(angle, 0.8);
  }
  EXPECT_GT(spread, 0.0) << "a tracked performance differs from the neutral face somewhere";
  EXPECT_EQ(lines.back()["rejected"], 0);
}

TEST_F(CliTest, SendInputRejectsMissingInputsAndConflictingSources) {
  const std::string key = keygen();
  std::string err;
  EXPECT_EQ(run({"send", "--to", "127.0.0.1:9", "--key", key, "--input", path("no-such-recording")}, nullptr, &err), 1);
  EXPECT_NE(err.find("no-such-recording"), std::string::npos) << err;
  // Said before the face model and the landmark models are read (seconds on a cold disk, tens of
  // seconds under a sanitizer): a missing model is not what is reported.
  EXPECT_EQ(run({"send", "--to", "127.0.0.1:9", "--key", key, "--input", path("no-such-recording"), "--model",
                 path("no-such-model.frm")},
                nullptr, &err),
            1);
  EXPECT_NE(err.find("no-such-recording"), std::string::npos) << err;
  EXPECT_EQ(err.find("no-such-model"), std::string::npos) << err;
  std::ofstream(path("p.jsonl")) << "";
  EXPECT_NE(run({"send", "--to", "127.0.0.1:9", "--key", key, "--input", path("x"), "--replay", path("p.jsonl")},
                nullptr, &err),
            0);
  EXPECT_NE(err.find("excludes"), std::string::npos) << err;
  EXPECT_EQ(run({"send", "--to", "127.0.0.1:9", "--key", key, "--input", "udp://9000"}, nullptr, &err), 1);
  EXPECT_NE(err.find("--input"), std::string::npos) << err;
}

}  // namespace
}  // namespace face_reenact::stream
