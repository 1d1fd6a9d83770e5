#version 450
// Non-indexed draw of 3 * T_drawn vertices: invocation 3t + k is corner k of drawn triangle t.
// Each corner carries a one-hot barycentric, so the rasteriser's perspective-correct
// interpolation yields the pixel's barycentric coordinates, and the flat triangle/vertex ids.
layout(std430, set = 0, binding = 0) readonly buffer CameraPositions { vec4 camera_positions[]; };
layout(std430, set = 0, binding = 1) readonly buffer CameraNormals { vec4 camera_normals[]; };
layout(std430, set = 0, binding = 2) readonly buffer Colors { vec4 colors[]; };
layout(std430, set = 0, binding = 3) readonly buffer DrawList { uvec4 draw_list[]; };  // v0, v1, v2, model triangle

layout(push_constant) uniform Push {
  float fx, fy, cx, cy;
  float width, height, near_plane, far_plane;
} pc;

layout(location = 0) out vec3 out_position;
layout(location = 1) out vec3 out_normal;
layout(location = 2) out vec3 out_color;
layout(location = 3) out vec3 out_barycentric;
layout(location = 4) flat out uvec4 out_ids;

void main() {
  const uint t = uint(gl_VertexIndex) / 3u;
  const uint corner = uint(gl_VertexIndex) % 3u;
  const uvec4 tri = draw_list[t];
  const uint v = tri[corner];
  // Triangles reaching outside [near, far] are dropped whole, as the CPU twin does: all three
  // corners go to the same point outside the view volume, a zero-area triangle.
  const float z0 = camera_positions[tri.x].z, z1 = camera_positions[tri.y].z, z2 = camera_positions[tri.z].z;
  const bool in_range = z0 > pc.near_plane && z0 < pc.far_plane && z1 > pc.near_plane && z1 < pc.far_plane &&
                        z2 > pc.near_plane && z2 < pc.far_plane;
  const vec3 x = camera_positions[v].xyz;
  out_position = x;
  out_normal = camera_normals[v].xyz;
  out_color = colors[v].xyz;
  out_barycentric = vec3(corner == 0u ? 1.0 : 0.0, corner == 1u ? 1.0 : 0.0, corner == 2u ? 1.0 : 0.0);
  out_ids = uvec4(tri.w + 1u, tri.x, tri.y, tri.z);
  if (!in_range) {
    gl_Position = vec4(-4.0, -4.0, 0.5, 1.0);
    return;
  }
  // Pinhole projection to framebuffer coordinates (pixel centre i at i + 0.5), then to NDC; the
  // clip w = z makes the hardware divide and interpolate perspective-correctly.
  const float u = pc.fx * x.x / x.z + pc.cx + 0.5;
  const float w = pc.fy * x.y / x.z + pc.cy + 0.5;
  const float ndc_x = u * 2.0 / pc.width - 1.0;
  const float ndc_y = w * 2.0 / pc.height - 1.0;
  const float depth = pc.far_plane * (x.z - pc.near_plane) / ((pc.far_plane - pc.near_plane) * x.z);
  gl_Position = vec4(ndc_x * x.z, ndc_y * x.z, depth * x.z, x.z);
}
