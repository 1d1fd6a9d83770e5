#pragma once
// The reenactment pipeline's two halves on two threads, for `face-reenact reenact` (files in,
// a file out): the caller tracks each frame (ReenactmentPipeline::Track, with the source actor
// tracked beside it), the frame's Render runs on a kept thread while the caller reads and tracks
// the next one, and the caller finishes each frame (writes it, scores it, tracks the output
// again) once it is rendered, in frame order. A file has no latency to lose, so this keeps both
// cores busier where one frame at a time left one idle during the render; the frames are the ones
// Process would give (ReenactPipelineTest.TrackAndRenderOverlappedOnTwoThreadsGiveProcessFrames).
// The demo stays one frame at a time: its calibrations, each already on both cores, are most of
// its time, and the overlap measured no gain there (docs/real-time.md). The live session has its
// own, optional, overlap (LiveSession::Options::overlap_frames): a camera's latency is what that
// one spends.
#include <functional>
#include <future>
#include <memory>
#include <utility>

#include "face_reenact/common/parallel.h"
#include "face_reenact/reenact/reenactment_pipeline.h"

namespace face_reenact::reenact {

// Frame: what finishing a frame needs, the caller's own per-frame data (the source expression
// its Render reads may live in it).
template <class Frame>
class OverlappedRender {
 public:
  using Finish = std::function<void(Frame& frame, const ReenactedFrame& out)>;

  OverlappedRender(ReenactmentPipeline& pipeline, Finish finish)
      : pipeline_(pipeline), finish_(std::move(finish)), thread_("fr-render") {}

  // Queues the Render of `tracked` with `source` (nullptr: the target's own expression; it must
  // point into *frame or outlive the render), behind the frame before, then finishes that one.
  void Push(std::unique_ptr<Frame> frame, TrackedTarget tracked, const SourceExpression* source) {
    auto next = std::make_unique<Slot>();
    next->frame = std::move(frame);
    next->out = thread_.Submit(
        [this, source, t = std::move(tracked)]() mutable { return pipeline_.Render(std::move(t), source); });
    std::unique_ptr<Slot> previous = std::exchange(in_flight_, std::move(next));
    if (previous) FinishSlot(*previous);
  }

  // Finishes the frame still rendering; after the last Push.
  void Drain() {
    if (!in_flight_) return;
    std::unique_ptr<Slot> last = std::move(in_flight_);
    FinishSlot(*last);
  }

 private:
  struct Slot {
    std::unique_ptr<Frame> frame;
    std::future<ReenactedFrame> out;
  };
  void FinishSlot(Slot& slot) {
    const ReenactedFrame out = slot.out.get();  // rethrows what Render threw
    finish_(*slot.frame, out);
  }

  ReenactmentPipeline& pipeline_;
  Finish finish_;
  std::unique_ptr<Slot> in_flight_;
  // Last: destroyed first, it lets a frame still in flight (an exception on its way) finish
  // rendering before the frame and the pipeline it reads go.
  NamedThread thread_;
};

}  // namespace face_reenact::reenact
