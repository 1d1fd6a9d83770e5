#version 450
// Writes the G-buffer: C_S, X_S, N_S, barycentrics, and (triangle + 1, v0, v1, v2); 0 = empty.
layout(location = 0) in vec3 in_position;
layout(location = 1) in vec3 in_normal;
layout(location = 2) in vec3 in_color;
layout(location = 3) in vec3 in_barycentric;
layout(location = 4) flat in uvec4 in_ids;

layout(location = 0) out vec4 out_color;
layout(location = 1) out vec4 out_position;
layout(location = 2) out vec4 out_normal;
layout(location = 3) out vec4 out_barycentric;
layout(location = 4) out uvec4 out_ids;

void main() {
  const float len = length(in_normal);
  out_color = vec4(in_color, 1.0);
  out_position = vec4(in_position, 1.0);
  out_normal = vec4(len > 0.0 ? in_normal / len : vec3(0.0), 0.0);
  // Interpolation keeps the sum at 1 only up to rounding; renormalise so the tracker can rely on it.
  const float sum = in_barycentric.x + in_barycentric.y + in_barycentric.z;
  out_barycentric = vec4(sum != 0.0 ? in_barycentric / sum : in_barycentric, 0.0);
  out_ids = in_ids;
}
