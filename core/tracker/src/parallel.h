#pragma once
// Fork-join over a fixed set of work items, for the tracker's CPU hot loops (residual and
// Jacobian rows, the PCG's products). Each item writes only its own output, and the items are
// fixed by the data, not by the thread count, so results are bit-identical for any count.
#include <functional>

namespace face_reenact::tracker::internal {

// Runs item(0) ... item(count - 1) on up to `threads` threads, the caller's among them, and
// returns when all have run. An exception from an item is rethrown here after the others have
// finished (workers never throw). When no thread can be started, the caller runs the rest.
void ParallelFor(int count, int threads, const std::function<void(int item)>& item);

}  // namespace face_reenact::tracker::internal
