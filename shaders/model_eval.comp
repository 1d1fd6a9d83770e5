#version 450
// The per-frame part of Eq. 1: positions = base_shape + E_exp delta, where base_shape =
// a_id + E_id alpha comes from identity_eval.comp. One thread per scalar row r in [0, 3N); the
// basis is column-major (3N x K), so a work group reads consecutive floats of each column.
layout(local_size_x = 64) in;

layout(std430, set = 0, binding = 0) readonly buffer BaseShape { float base_shape[]; };
layout(std430, set = 0, binding = 1) readonly buffer ExpressionBasis { float expression_basis[]; };
layout(std430, set = 0, binding = 2) readonly buffer Coefficients { float coeffs[]; };  // alpha | delta | beta
layout(std430, set = 0, binding = 3) writeonly buffer Shape { float shape[]; };

layout(push_constant) uniform Push {
  uint rows;  // 3N
  uint num_expression;
  uint expression_offset;  // index of delta_0 in coeffs
  uint pad;
} pc;

void main() {
  const uint r = gl_GlobalInvocationID.x;
  if (r >= pc.rows) return;
  float s = base_shape[r];
  for (uint j = 0; j < pc.num_expression; ++j) s += expression_basis[j * pc.rows + r] * coeffs[pc.expression_offset + j];
  shape[r] = s;
}
