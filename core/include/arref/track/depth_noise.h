// How noisy a stream's depth is, measured from its own frames: the tracker's agreement tolerance
// was set on a sensor of about 1 % of range (HoloLens 2's long-throw camera), and a noisier one
// (a stereo depth API, a worn or sunlit time-of-flight camera) would fail it on most pixels.
#pragma once

#include <cstddef>
#include <deque>
#include <optional>

#include "arref/track/depth_frame.h"
#include "arref/track/model_caster.h"

namespace arref {

// The depth noise of one unwrapped frame as a fraction of range (sigma / z), from the second
// differences of neighbouring pixels along rows: on a surface that is smooth at the pixel's
// scale d[u-1] - 2 d[u] + d[u+1] is the noise alone, with 6 sigma^2 of variance (a plane's own
// curvature there is a tenth of a millimetre at 2 m), and depth edges, flying pixels and missing
// returns are outliers a median ignores (MAD, 1.4826 per sigma). Every row_step-th row. None
// when fewer than min_samples triples of pixels have a return, or for a wrapped frame (its
// readings are not ranges: a far surface read modulo the wrap would count its noise against a
// near range).
std::optional<double> FrameDepthNoise(const DepthFrame& frame, int row_step = 4, std::size_t min_samples = 500);

// The same for a wrapped frame (AHAT: ranges modulo wrap_m), where only a model of the scene
// says how far a reading is: measured at the pixels of `expected`'s grid where it has a depth
// (the robot's model as the tracker places it, seen from the frame's camera). Neighbours'
// differences are taken modulo the wrap, so a wrap between them costs nothing, and the second
// difference is divided by the reading unwrapped to the alias nearest the expected depth. None
// for an unwrapped frame, or with fewer than min_samples such triples.
std::optional<double> WrappedFrameDepthNoise(const DepthFrame& frame, const ModelView& expected,
                                             std::size_t min_samples = 200);

// The median of the last `frames` frames' figures: one frame's edges and props move it, the
// sensor's noise does not change between frames.
class DepthNoiseEstimate {
 public:
  explicit DepthNoiseEstimate(std::size_t frames = 30) : frames_(frames) {}
  void Add(double fraction);  // a non-finite figure is ignored
  std::optional<double> fraction() const { return median_; }  // none before the first figure

 private:
  std::size_t frames_;
  std::deque<double> recent_;
  std::optional<double> median_;  // of recent_, kept as figures come
};

}  // namespace arref
