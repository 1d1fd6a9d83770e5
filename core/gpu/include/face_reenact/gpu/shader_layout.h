#pragma once
// GLM's GLSL-shaped types for the host-side mirrors of the shaders' push-constant blocks and
// buffer layouts (renderer.cc, the tracker's vulkan_solver.cc). A mirror is written once, in
// GLSL's terms: the block's members in its order, with its names and these types:
//
//   GLSL    host              std430 (storage buffers, push constants)   std140 (uniform blocks)
//   float   float             size 4, align 4                            same
//   uint    glm::uint         size 4, align 4                            same
//   int     std::int32_t      size 4, align 4                            same
//   uvec2   glm::uvec2        size 8, align 8                            same
//   vec4    glm::vec4         size 16, align 16                          same
//   uvec4   glm::uvec4        size 16, align 16                          same
//   T[n]    T[n]              stride: T's size rounded up to its align   stride rounded up to 16
//   vec3    (avoid)           size 12, align 16                          same
//
// GLM's default types are packed: glm::vec4 is 16 bytes but aligned to 4 in C++, glm::vec3 is
// 12 bytes aligned to 4. So C++ places a member where std430 does only when every vector member
// already sits at a multiple of its GLSL alignment; each mirror proves that with a
// static_assert(offsetof(S, member) == N) per member and a static_assert(sizeof(S) == N), and a
// wrong type, order or padding fails the build. The shaders use no vec3 in their blocks (a vec4
// with an unused w instead), and neither do the mirrors: after a vec3 std430 packs a scalar into
// its fourth slot but moves a vec2 or vec4 on to the next 16, and glm::vec3 gets only the first.
// No GLM_FORCE_* setting is used: GLM_FORCE_DEFAULT_ALIGNED_GENTYPES would align vec4 to 16 but
// also make glm::vec3 16 bytes, wrong for a vec3 followed by a float (checked: GLM 0.9.9.8).
//
// A GLSL struct's alignment is its largest member's, and std430 rounds the struct's size up to it;
// a mirror of a struct with vector members says so with alignas (FrameBlock in renderer.cc:
// alignas(16), 172 bytes of members, 176 in all). Blocks of 4-byte scalars need no such care.
//
// Eigen stays the library of the host's linear algebra; GLM is used only to state these layouts.
#include <glm/vec2.hpp>
#include <glm/vec4.hpp>

#include <cstdint>
#include <type_traits>

namespace face_reenact::gpu {

// The assumptions above, checked once for the GLM in use.
static_assert(sizeof(glm::uint) == 4 && sizeof(float) == 4 && sizeof(std::int32_t) == 4);
static_assert(sizeof(glm::uvec2) == 8 && sizeof(glm::vec4) == 16 && sizeof(glm::uvec4) == 16);
static_assert(std::is_standard_layout_v<glm::vec4> && std::is_trivially_copyable_v<glm::vec4>,
              "offsetof and memcpy uploads need standard-layout, trivially copyable GLM vectors");
static_assert(std::is_standard_layout_v<glm::uvec4> && std::is_trivially_copyable_v<glm::uvec4>);

}  // namespace face_reenact::gpu
