#pragma once
// Writes one instance of the face model as a mesh a person can open in a viewer (MeshLab,
// Blender): Wavefront OBJ (with per-vertex colours and per-corner UVs) or binary PLY (with
// per-vertex colours). The format is chosen by the file extension.
#include <Eigen/Core>
#include <string>
#include <vector>

#include "face_reenact/model/face_model.h"

namespace face_reenact {

struct MeshInstance {
  Eigen::VectorXf positions;  // 3N, metres
  Eigen::VectorXf colours;    // 3N, linear RGB in [0,1] (written gamma-encoded as sRGB)
};

// Writes the triangles whose three vertices belong to one of `parts` (all parts when empty).
// Throws face_reenact::Error for an unknown extension or an unwritable path.
void export_mesh(const FaceModel& model, const MeshInstance& instance, const std::vector<FacePart>& parts,
                 const std::string& path);

}  // namespace face_reenact
