#include "face_reenact/stream/protocol.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <set>

#include "face_reenact/common/error.h"
#include "stream_test_util.h"

namespace face_reenact::stream {
namespace {

using testing::encode;
using testing::make_frame;
using testing::RawDatagram;
using testing::spec_encode;
using testing::spec_flags;
using testing::spec_payload;
using testing::test_key;

void expect_same_frame(const ExpressionFrame& a, const ExpressionFrame& b) {
  EXPECT_EQ(a.capture_time_us, b.capture_time_us);
  EXPECT_EQ(a.expression, b.expression);
  EXPECT_EQ(a.neutral_subtracted, b.neutral_subtracted);
  if (!a.neutral_subtracted) EXPECT_EQ(a.neutral, b.neutral);
  EXPECT_EQ(a.has_rotation, b.has_rotation);
  if (a.has_rotation) EXPECT_EQ(a.rotation, b.rotation);
  EXPECT_EQ(a.has_translation, b.has_translation);
  if (a.has_translation) EXPECT_EQ(a.translation, b.translation);
}

TEST(StreamProtocol, SizesMatchTheSpec) {
  EXPECT_EQ(kMinDatagramSize, 276u);
  EXPECT_EQ(kMaxDatagramSize, 508u);
  EXPECT_EQ(datagram_size_for_flags(kNeutralSubtracted), 276u);
  EXPECT_EQ(datagram_size_for_flags(kHasNeutral | kHasRotation | kHasTranslation), 508u);
  EXPECT_EQ(datagram_size_for_flags(kNeutralSubtracted | kHasRotation), 288u);
}

TEST(StreamProtocol, RoundTripsEveryFlagCombination) {
  const StreamKey key = test_key();
  for (int neutral = 0; neutral < 2; ++neutral)
    for (int rot = 0; rot < 2; ++rot)
      for (int trans = 0; trans < 2; ++trans) {
        ExpressionFrame f = make_frame(100 + neutral * 4 + rot * 2 + trans, neutral, false);
        f.has_rotation = rot;
        f.rotation = {0.3f, -0.1f, 0.2f};
        f.has_translation = trans;
        f.translation = {0.05f, 0.f, 0.7f};
        const auto d = encode(key, 42, 1234567, f);
        EXPECT_EQ(d.size(), datagram_size_for_flags(spec_flags(f)));
        DatagramHeader h;
        ExpressionFrame out;
        ASSERT_EQ(decode_datagram(key, d, &h, &out), DatagramError::kNone);
        EXPECT_EQ(h.stream_id, 42u);
        EXPECT_EQ(h.sequence, 1234567u);
        EXPECT_EQ(h.flags, spec_flags(f));
        expect_same_frame(f, out);
      }
}

TEST(StreamProtocol, LayoutMatchesTheIndependentSpecEncoder) {
  // A datagram built by the test's own encoder from the spec must decode, and the library's
  // datagram must have the spec's cleartext header.
  const StreamKey key = test_key();
  const ExpressionFrame f = make_frame(5, true, true);
  RawDatagram r;
  r.flags = spec_flags(f);
  r.stream_id = 0xA1B2C3D4u;
  r.sequence = 0x0102030405060708ull;
  r.payload = spec_payload(f);
  DatagramHeader h;
  ExpressionFrame out;
  ASSERT_EQ(decode_datagram(key, spec_encode(key, r), &h, &out), DatagramError::kNone);
  expect_same_frame(f, out);

  const auto d = encode(key, 0xA1B2C3D4u, 0x0102030405060708ull, f);
  const std::vector<uint8_t> header(d.begin(), d.begin() + 20);
  const std::vector<uint8_t> expected = {'F', 'R', 'E', 'X', 1, r.flags, 0, 0, 0xD4, 0xC3, 0xB2, 0xA1,
                                         8, 7, 6, 5, 4, 3, 2, 1};
  EXPECT_EQ(header, expected);
}

TEST(StreamProtocol, NoncesDifferBetweenDatagrams) {
  const StreamKey key = test_key();
  const ExpressionFrame f = make_frame(1);
  const auto a = encode(key, 1, 1, f), b = encode(key, 1, 1, f);
  EXPECT_NE(std::vector<uint8_t>(a.begin() + 20, a.begin() + 44), std::vector<uint8_t>(b.begin() + 20, b.begin() + 44));
  EXPECT_NE(a, b);
}

TEST(StreamProtocol, EveryBitFlipIsRejected) {
  const StreamKey key = test_key();
  for (bool big : {false, true}) {
    const auto d = encode(key, 9, 77, make_frame(3, big, big));
    for (size_t i = 0; i < d.size(); ++i) {
      for (uint8_t mask : {uint8_t(0x01), uint8_t(0x80), uint8_t(0xFF)}) {
        auto bad = d;
        bad[i] ^= mask;
        DatagramHeader h;
        ExpressionFrame out;
        const DatagramError e = decode_datagram(key, bad, &h, &out);
        ASSERT_NE(e, DatagramError::kNone) << "byte " << i << " mask " << int(mask);
        if (i >= 8) EXPECT_EQ(e, DatagramError::kAuthFailed) << "byte " << i;  // ids, nonce, ciphertext, tag
        EXPECT_EQ(out.capture_time_us, 0u);  // nothing leaks out of a rejected datagram
      }
    }
  }
}

TEST(StreamProtocol, HeaderCorruptionsHaveSpecificReasons) {
  const StreamKey key = test_key();
  auto d = encode(key, 1, 1, make_frame(1));
  DatagramHeader h;
  ExpressionFrame f;
  auto with = [&](size_t i, uint8_t v) {
    auto b = d;
    b[i] = v;
    return decode_datagram(key, b, &h, &f);
  };
  EXPECT_EQ(with(0, 'X'), DatagramError::kBadMagic);
  EXPECT_EQ(with(4, 2), DatagramError::kBadVersion);
  EXPECT_EQ(with(5, kNeutralSubtracted | 0x10), DatagramError::kBadFlags);    // unknown bit
  EXPECT_EQ(with(5, kNeutralSubtracted | kHasNeutral), DatagramError::kBadFlags);  // both
  EXPECT_EQ(with(5, kHasRotation), DatagramError::kBadFlags);                // neither
  EXPECT_EQ(with(6, 1), DatagramError::kBadFlags);                           // reserved
  EXPECT_EQ(with(5, kHasNeutral), DatagramError::kTruncated);                // flags want 208 more bytes
  auto big = encode(key, 1, 1, make_frame(1, true, false));
  big[5] = kNeutralSubtracted;
  EXPECT_EQ(decode_datagram(key, big, &h, &f), DatagramError::kOversized);   // flags want fewer bytes
}

TEST(StreamProtocol, TruncatedAndOversizedDatagramsAreRejected) {
  const StreamKey key = test_key();
  const auto d = encode(key, 1, 1, make_frame(2, true, true));
  DatagramHeader h;
  ExpressionFrame f;
  for (size_t n = 0; n < d.size(); ++n) {
    const DatagramError e = decode_datagram(key, std::span<const uint8_t>(d.data(), n), &h, &f);
    EXPECT_EQ(e, DatagramError::kTruncated) << n;
  }
  for (size_t extra : {1u, 7u, 1000u, 65000u}) {
    auto b = d;
    b.resize(d.size() + extra, 0xAB);
    EXPECT_EQ(decode_datagram(key, b, &h, &f), DatagramError::kOversized) << extra;
  }
}

TEST(StreamProtocol, WrongKeyFailsAuthentication) {
  const auto d = encode(test_key(1), 1, 1, make_frame(1));
  DatagramHeader h;
  ExpressionFrame f;
  EXPECT_EQ(decode_datagram(test_key(2), d, &h, &f), DatagramError::kAuthFailed);
  EXPECT_EQ(decode_datagram(test_key(1), d, &h, &f), DatagramError::kNone);
}

TEST(StreamProtocol, AuthenticatedButInvalidValuesAreRejected) {
  const StreamKey key = test_key();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  struct Case {
    const char* name;
    std::function<void(ExpressionFrame&)> spoil;
  };
  const std::vector<Case> cases = {
      {"nan expression", [&](ExpressionFrame& f) { f.expression[17] = nan; }},
      {"inf expression", [&](ExpressionFrame& f) { f.expression[0] = -inf; }},
      {"huge expression", [&](ExpressionFrame& f) { f.expression[51] = 3.f; }},
      {"nan neutral", [&](ExpressionFrame& f) { f.neutral_subtracted = false; f.neutral[4] = nan; }},
      {"nan rotation", [&](ExpressionFrame& f) { f.has_rotation = true; f.rotation[1] = nan; }},
      {"huge rotation", [&](ExpressionFrame& f) { f.has_rotation = true; f.rotation = {7.f, 0.f, 0.f}; }},
      {"inf translation", [&](ExpressionFrame& f) { f.has_translation = true; f.translation[2] = inf; }},
      {"far translation", [&](ExpressionFrame& f) { f.has_translation = true; f.translation[0] = 500.f; }},
  };
  for (const Case& c : cases) {
    ExpressionFrame f = make_frame(11);
    c.spoil(f);
    std::string why;
    EXPECT_FALSE(frame_values_valid(f, &why)) << c.name;
    EXPECT_FALSE(why.empty());
    // The library refuses to send it...
    std::array<uint8_t, kMaxDatagramSize> buf;
    EXPECT_THROW(encode_datagram(key, 1, 1, f, buf), Error) << c.name;
    // ...and a receiver refuses it even when it is correctly authenticated.
    RawDatagram r;
    r.flags = spec_flags(f);
    r.payload = spec_payload(f);
    DatagramHeader h;
    ExpressionFrame out;
    EXPECT_EQ(decode_datagram(key, spec_encode(key, r), &h, &out), DatagramError::kInvalidValues) << c.name;
    EXPECT_EQ(out.expression[17], 0.f);
  }
}

TEST(StreamProtocol, RelativeExpressionSubtractsTheNeutral) {
  ExpressionFrame f = make_frame(4, true);
  const auto r = f.relative_expression();
  for (int i = 0; i < kNumCoefficients; ++i) EXPECT_FLOAT_EQ(r[i], f.expression[i] - f.neutral[i]);
  f.neutral_subtracted = true;
  EXPECT_EQ(f.relative_expression(), f.expression);
}

TEST(StreamProtocol, ErrorNamesAreDistinct) {
  std::set<std::string> names;
  for (int i = 0; i < kNumDatagramErrors; ++i) names.insert(datagram_error_name(static_cast<DatagramError>(i)));
  EXPECT_EQ(names.size(), static_cast<size_t>(kNumDatagramErrors));
}

}  // namespace
}  // namespace face_reenact::stream
