#include "frame_processor.h"

namespace face_reenact::live {
namespace {

class RawProcessor : public FrameProcessor {
 public:
  ProcessedFrame process(const capture::RgbdFrame& target, const ExpressionInput&) override {
    ProcessedFrame out;
    out.bgr = target.color;
    out.tracking = TrackingState::kOff;
    return out;
  }
  void request_calibration() override {}
};

}  // namespace

std::unique_ptr<FrameProcessor> make_raw_processor() { return std::make_unique<RawProcessor>(); }

}  // namespace face_reenact::live
