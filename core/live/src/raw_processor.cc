#include "frame_processor.h"

namespace face_reenact::live {
namespace {

class RawProcessor : public FrameProcessor {
 public:
  struct Staged : StagedFrame {
    cv::Mat bgr;
  };
  std::unique_ptr<StagedFrame> track(const capture::RgbdFrame& target, const ExpressionInput&, ActorOutcome*) override {
    auto staged = std::make_unique<Staged>();
    staged->bgr = target.color;
    return staged;
  }
  ProcessedFrame render(std::unique_ptr<StagedFrame> staged) override {
    ProcessedFrame out;
    out.bgr = static_cast<Staged&>(*staged).bgr;
    out.tracking = TrackingState::kOff;
    return out;
  }
  void request_calibration() override {}
};

}  // namespace

std::shared_ptr<FrameProcessor> make_raw_processor() { return std::make_shared<RawProcessor>(); }

}  // namespace face_reenact::live
