#include "video_output.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

extern "C" {
#include <libavcodec/avcodec.h>
#include <libavformat/avformat.h>
#include <libswscale/swscale.h>
}

namespace face_reenact::cli {

namespace {

// x264's speed against size: "veryfast" drops the trellis quantisation and the deeper motion
// search that made "medium" cost about 20 ms per 640x480 frame on one core here; CRF 21 buys back
// the quality that costs (the webcam clip against its frames: medium/23 31.63 dB, veryfast/21
// 31.65 dB).
constexpr const char* kX264Preset = "veryfast";
constexpr const char* kX264Crf = "21";

std::string av_error(int code) {
  char text[AV_ERROR_MAX_STRING_SIZE] = {0};
  av_strerror(code, text, sizeof text);
  return text;
}

}  // namespace

struct Mp4Writer::Impl {
  AVFormatContext* format = nullptr;
  AVCodecContext* encoder = nullptr;
  AVStream* stream = nullptr;
  AVFrame* frame = nullptr;
  AVPacket* packet = nullptr;
  SwsContext* convert = nullptr;
  cv::Size size;          // as the caller gives frames
  cv::Size coded;         // even sides, as 4:2:0 needs (an odd side repeats its last row/column)
  cv::Mat padded;         // the frame grown to `coded`
  int64_t next_pts = 0;
  bool header_written = false, finished = false;

  ~Impl() {
    sws_freeContext(convert);
    av_packet_free(&packet);
    av_frame_free(&frame);
    avcodec_free_context(&encoder);
    if (format) {
      if (format->pb) avio_closep(&format->pb);
      avformat_free_context(format);
    }
  }

  // Sends one frame (nullptr: the end) and writes every packet the encoder has ready.
  void Encode(const AVFrame* f, const std::string& path) {
    int err = avcodec_send_frame(encoder, f);
    if (err < 0) throw Error("cannot write video '" + path + "': encoding failed (" + av_error(err) + ")");
    for (;;) {
      err = avcodec_receive_packet(encoder, packet);
      if (err == AVERROR(EAGAIN) || err == AVERROR_EOF) return;
      if (err < 0) throw Error("cannot write video '" + path + "': encoding failed (" + av_error(err) + ")");
      // One frame's time (x264 leaves it 0): without it the file's length lacks the last frame,
      // and players read its rate as (n - 1) / n of the real one.
      if (packet->duration == 0) packet->duration = 1;
      av_packet_rescale_ts(packet, encoder->time_base, stream->time_base);
      packet->stream_index = stream->index;
      err = av_interleaved_write_frame(format, packet);  // takes the packet's data and unrefs it
      if (err < 0) throw Error("cannot write video '" + path + "': " + av_error(err) + " (disk full?)");
    }
  }
};

Mp4Writer::Mp4Writer(const std::string& path, double fps, cv::Size size) : path_(path), impl_(std::make_unique<Impl>()) {
  if (size.width <= 0 || size.height <= 0) throw Error("cannot write video '" + path + "': empty frame size");
  if (!(fps > 0) || !std::isfinite(fps)) throw Error("cannot write video '" + path + "': frame rate " + std::to_string(fps));
  Impl& m = *impl_;
  m.size = size;
  m.coded = cv::Size(size.width + size.width % 2, size.height + size.height % 2);
  auto fail = [&](const std::string& why) { return Error("cannot write video '" + path + "': " + why); };
  // FFmpeg's errors only (as OpenCV's reader sets it): libx264 writes a page of statistics otherwise.
  if (av_log_get_level() > AV_LOG_ERROR) av_log_set_level(AV_LOG_ERROR);
  int err = avformat_alloc_output_context2(&m.format, nullptr, "mp4", path.c_str());
  if (err < 0 || !m.format) throw fail("no mp4 muxer in FFmpeg (" + av_error(err) + ")");

  // libx264 when this FFmpeg has it (Debian's does), else its own MPEG-4 part 2 encoder.
  const AVCodec* codec = avcodec_find_encoder_by_name("libx264");
  if (!codec) codec = avcodec_find_encoder(AV_CODEC_ID_MPEG4);
  if (!codec) throw fail("no mp4 video encoder (libx264, mpeg4) in FFmpeg");
  const bool x264 = std::string(codec->name) == "libx264";

  m.stream = avformat_new_stream(m.format, nullptr);
  m.encoder = avcodec_alloc_context3(codec);
  m.frame = av_frame_alloc();
  m.packet = av_packet_alloc();
  if (!m.stream || !m.encoder || !m.frame || !m.packet) throw fail("out of memory");
  m.encoder->width = m.coded.width;
  m.encoder->height = m.coded.height;
  m.encoder->pix_fmt = AV_PIX_FMT_YUV420P;
  m.encoder->framerate = av_d2q(fps, 100000);
  m.encoder->time_base = av_inv_q(m.encoder->framerate);
  if (m.format->oformat->flags & AVFMT_GLOBALHEADER) m.encoder->flags |= AV_CODEC_FLAG_GLOBAL_HEADER;
  AVDictionary* options = nullptr;
  if (x264) {
    av_dict_set(&options, "preset", kX264Preset, 0);
    av_dict_set(&options, "crf", kX264Crf, 0);
  } else {
    // The fallback has no constant-quality mode set here: a rate ample for its frames (4 bits a
    // pixel a second, at most 8 Mbit/s).
    m.encoder->bit_rate = static_cast<int64_t>(std::min(8e6, 4.0 * fps * size.area()));
  }
  err = avcodec_open2(m.encoder, codec, &options);
  av_dict_free(&options);
  if (err < 0) throw fail(std::string("cannot open the ") + codec->name + " encoder (" + av_error(err) + ")");
  codec_ = x264 ? std::string("h264 (libx264 ") + kX264Preset + ", crf " + kX264Crf + ")" : std::string(codec->name);
  err = avcodec_parameters_from_context(m.stream->codecpar, m.encoder);
  if (err < 0) throw fail(av_error(err));
  m.stream->time_base = m.encoder->time_base;

  m.frame->format = m.encoder->pix_fmt;
  m.frame->width = m.coded.width;
  m.frame->height = m.coded.height;
  err = av_frame_get_buffer(m.frame, 0);
  if (err < 0) throw fail(av_error(err));
  m.convert = sws_getContext(m.coded.width, m.coded.height, AV_PIX_FMT_BGR24, m.coded.width, m.coded.height,
                             AV_PIX_FMT_YUV420P, SWS_BILINEAR, nullptr, nullptr, nullptr);
  if (!m.convert) throw fail("no BGR to YUV 4:2:0 conversion in FFmpeg");

  err = avio_open(&m.format->pb, path.c_str(), AVIO_FLAG_WRITE);
  if (err < 0) throw fail(av_error(err));
  // The index at the front, so a browser plays the file while it downloads.
  AVDictionary* muxer = nullptr;
  av_dict_set(&muxer, "movflags", "+faststart", 0);
  err = avformat_write_header(m.format, &muxer);
  av_dict_free(&muxer);
  if (err < 0) throw fail(av_error(err));
  m.header_written = true;
}

Mp4Writer::~Mp4Writer() {
  try {
    close();
  } catch (const std::exception&) {
    // A destructor after an error elsewhere: the file stays as far as it got.
  }
}

void Mp4Writer::write(const cv::Mat& bgr) {
  Impl& m = *impl_;
  if (m.finished) throw Error("video '" + path_ + "': written after it was closed");
  if (bgr.type() != CV_8UC3 || bgr.size() != m.size)
    throw Error("video '" + path_ + "': frame of " + std::to_string(bgr.cols) + "x" + std::to_string(bgr.rows) +
                " (type " + std::to_string(bgr.type()) + "), expected " + std::to_string(m.size.width) + "x" +
                std::to_string(m.size.height) + " BGR");
  const cv::Mat* source = &bgr;
  if (m.coded != m.size) {
    cv::copyMakeBorder(bgr, m.padded, 0, m.coded.height - m.size.height, 0, m.coded.width - m.size.width, cv::BORDER_REPLICATE);
    source = &m.padded;
  }
  int err = av_frame_make_writable(m.frame);  // the encoder may still hold the last one
  if (err < 0) throw Error("video '" + path_ + "': " + av_error(err));
  const uint8_t* planes[1] = {source->data};
  const int strides[1] = {static_cast<int>(source->step[0])};
  sws_scale(m.convert, planes, strides, 0, m.coded.height, m.frame->data, m.frame->linesize);
  m.frame->pts = m.next_pts++;
  m.Encode(m.frame, path_);
}

void Mp4Writer::close() {
  Impl& m = *impl_;
  if (m.finished || !m.header_written) return;
  m.finished = true;
  m.Encode(nullptr, path_);
  const int err = av_write_trailer(m.format);
  if (err < 0) throw Error("cannot finish video '" + path_ + "': " + av_error(err) + " (disk full?)");
  avio_closep(&m.format->pb);
}

}  // namespace face_reenact::cli
