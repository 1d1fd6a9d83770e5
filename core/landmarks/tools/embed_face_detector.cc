// Build tool: writes dlib's frontal face detector (HOG features, five view-specific linear
// filters) as a C++ source that embeds it in dlib's own serialisation.
//
// Why: dlib::get_frontal_face_detector() decodes its built-in model with dlib's entropy decoder,
// about 350 ms of every process that looks for a face (measured 2026-12-01, the 2-core machine,
// release build), while deserialising the same detector from its serialisation takes 2 ms. The
// decoding happens once, here, at build time; the result is dlib's detector byte for byte
// (DlibBackend.TheEmbeddedFaceDetectorIsDlibsOwn).
//
// Usage: fr_embed_face_detector OUT.cc
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>

#include <dlib/image_processing/frontal_face_detector.h>
#include <dlib/serialize.h>

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s OUT.cc\n", argv[0]);
    return 2;
  }
  std::ostringstream blob;
  dlib::serialize(dlib::get_frontal_face_detector(), blob);
  const std::string bytes = blob.str();
  const std::string out_path = argv[1], partial = out_path + ".partial";
  {
    std::ofstream out(partial, std::ios::binary | std::ios::trunc);
    out << "// Generated at build time by fr_embed_face_detector (core/landmarks/tools/embed_face_detector.cc):\n"
           "// dlib's frontal face detector in dlib's serialisation. Do not edit.\n"
           "#include <cstddef>\n\n"
           "namespace face_reenact::landmarks::detail {\n\n"
           "extern const unsigned char kFrontalFaceDetector[];\n"
           "extern const std::size_t kFrontalFaceDetectorSize;\n"
           "const unsigned char kFrontalFaceDetector[] = {\n";
    char number[8];
    for (size_t i = 0; i < bytes.size(); ++i) {
      std::snprintf(number, sizeof(number), "%u,", static_cast<unsigned>(static_cast<unsigned char>(bytes[i])));
      out << number << ((i + 1) % 24 == 0 ? "\n" : "");
    }
    out << "};\nconst std::size_t kFrontalFaceDetectorSize = " << bytes.size() << ";\n\n"
        << "}  // namespace face_reenact::landmarks::detail\n";
    if (!out) {
      std::fprintf(stderr, "fr_embed_face_detector: cannot write '%s'\n", partial.c_str());
      return 1;
    }
  }
  if (std::rename(partial.c_str(), out_path.c_str()) != 0) {
    std::fprintf(stderr, "fr_embed_face_detector: cannot move '%s' to '%s'\n", partial.c_str(), out_path.c_str());
    return 1;
  }
  return 0;
}
