#include "gpu/dvd_shader.hpp"

namespace proxima::gpu {

namespace {

// The kernel, one invocation per sample. Its arithmetic is the CPU backend's operation sequence
// (engine/src/culling/dvd_cpu.cpp, the comment block "THE OPERATION SEQUENCE"), spelled out
// operation for operation with the same parenthesization:
//  * every intermediate is a `precise` scalar: the compiler may neither reassociate nor contract
//    a product and a sum into a fused multiply-add (the CPU file is compiled with
//    -ffp-contract=off for the same reason), nor use any other value-changing rewrite;
//  * no dot(), length(), min(), max(), clamp() or other library call (their internal order is the
//    driver's choice): only +, -, *, / and the final sqrt;
//  * triangles are visited in the bucket's ascending order, and a candidate replaces the best one
//    only if strictly smaller, so ties keep the smallest index, as on the CPU.
// IEEE single precision rounds +, -, * and / correctly and so do the CPU and llvmpipe (which
// compiles / and sqrt to the x86 instructions divps / sqrtps): the two backends give identical
// bits. GLSL itself only promises correctly rounded +, -, * and up to 2.5 ulp for / and about
// 3 ulp for sqrt (GLSL 4.30 §4.7.1): on a GPU the results may differ in the last bits, which
// kernel_error_bound charges (4u per division and square root).
//
// Storage: eight std430 blocks (the OpenGL 4.3 minimum per compute shader). The samples are
// packed point, owner, bucket (20 bytes); the sample and output blocks are bound per dispatch
// chunk (egl_backend.cpp), so index i is relative to the chunk.
const char* const SOURCE = R"glsl(#version 430 core
layout(local_size_x = LOCAL_SIZE) in;

layout(std430, binding = 0) readonly restrict buffer TriangleVertices { float triangle_vertices[]; };
layout(std430, binding = 1) readonly restrict buffer TriangleIndices { uint triangle_indices[]; };
layout(std430, binding = 2) readonly restrict buffer TriangleObject { uint triangle_object[]; };
layout(std430, binding = 3) readonly restrict buffer BucketOffsets { uint bucket_offsets[]; };
layout(std430, binding = 4) readonly restrict buffer BucketTriangles { uint bucket_triangles[]; };
struct Sample { float x; float y; float z; uint owner; uint bucket; };
layout(std430, binding = 5) readonly restrict buffer Samples { Sample samples[]; };
layout(std430, binding = 6) writeonly restrict buffer OutDistance { float out_distance[]; };
layout(std430, binding = 7) writeonly restrict buffer OutNearest { uint out_nearest[]; };

uniform uint u_sample_count;  // samples in this dispatch
uniform uint u_mode;          // 0: inter-object, 1: intra-object
uniform float u_radius;

const uint NO_TRIANGLE = 0xffffffffu;
const float TOL = 9.5367431640625e-07;  // 2^-20, exact in float

// Squared distance from p to segment [v0, v1], and the edge's and w's squared lengths:
// (ss, ee, ww).
vec3 segment(vec3 p, vec3 v0, vec3 v1) {
    precise float wx = p.x - v0.x;
    precise float wy = p.y - v0.y;
    precise float wz = p.z - v0.z;
    precise float ex = v1.x - v0.x;
    precise float ey = v1.y - v0.y;
    precise float ez = v1.z - v0.z;
    precise float ee = ((ex * ex) + (ey * ey)) + (ez * ez);
    precise float ww = ((wx * wx) + (wy * wy)) + (wz * wz);
    precise float we = ((wx * ex) + (wy * ey)) + (wz * ez);
    precise float t = 0.0;
    if (ee > 0.0) {
        t = we / ee;
        if (t < 0.0) {
            t = 0.0;
        }
        if (t > 1.0) {
            t = 1.0;
        }
    }
    precise float dx = wx - (t * ex);
    precise float dy = wy - (t * ey);
    precise float dz = wz - (t * ez);
    precise float ss = ((dx * dx) + (dy * dy)) + (dz * dz);
    return vec3(ss, ee, ww);
}

// ((v1 - v0) x (p - v0)) . n
float side(vec3 p, vec3 v0, vec3 v1, float nx, float ny, float nz) {
    precise float ex = v1.x - v0.x;
    precise float ey = v1.y - v0.y;
    precise float ez = v1.z - v0.z;
    precise float wx = p.x - v0.x;
    precise float wy = p.y - v0.y;
    precise float wz = p.z - v0.z;
    precise float cx = (ey * wz) - (ez * wy);
    precise float cy = (ez * wx) - (ex * wz);
    precise float cz = (ex * wy) - (ey * wx);
    precise float r = ((cx * nx) + (cy * ny)) + (cz * nz);
    return r;
}

float point_triangle_distance_squared(vec3 p, vec3 a, vec3 b, vec3 c) {
    precise vec3 s0 = segment(p, a, b);
    precise vec3 s1 = segment(p, b, c);
    precise vec3 s2 = segment(p, c, a);
    precise float best = s0.x;
    if (s1.x < best) {
        best = s1.x;
    }
    if (s2.x < best) {
        best = s2.x;
    }
    precise float abx = b.x - a.x;
    precise float aby = b.y - a.y;
    precise float abz = b.z - a.z;
    precise float acx = c.x - a.x;
    precise float acy = c.y - a.y;
    precise float acz = c.z - a.z;
    precise float apx = p.x - a.x;
    precise float apy = p.y - a.y;
    precise float apz = p.z - a.z;
    precise float nx = (aby * acz) - (abz * acy);
    precise float ny = (abz * acx) - (abx * acz);
    precise float nz = (abx * acy) - (aby * acx);
    precise float nn = ((nx * nx) + (ny * ny)) + (nz * nz);
    if (nn > 0.0) {
        precise float q0 = side(p, a, b, nx, ny, nz);
        precise float q1 = side(p, b, c, nx, ny, nz);
        precise float q2 = side(p, c, a, nx, ny, nz);
        precise float g = s0.y + s2.y;
        precise float tol0 = TOL * ((s0.y + s0.z) * g);
        precise float tol1 = TOL * ((s1.y + s1.z) * g);
        precise float tol2 = TOL * ((s2.y + s2.z) * g);
        if (q0 >= -tol0 && q1 >= -tol1 && q2 >= -tol2) {
            precise float h = ((nx * apx) + (ny * apy)) + (nz * apz);
            precise float f = (h * h) / nn;
            if (f < best) {
                best = f;
            }
        }
    }
    return best;
}

vec3 corner(uint t, uint k) {
    uint base = 9u * t + 3u * k;
    return vec3(triangle_vertices[base], triangle_vertices[base + 1u],
                triangle_vertices[base + 2u]);
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= u_sample_count) {
        return;
    }
    Sample s = samples[i];
    vec3 p = vec3(s.x, s.y, s.z);
    uint owner = s.owner;
    uint o0 = triangle_indices[3u * owner];
    uint o1 = triangle_indices[3u * owner + 1u];
    uint o2 = triangle_indices[3u * owner + 2u];
    uint owner_object = triangle_object[owner];
    precise float r2 = u_radius * u_radius;
    float best = uintBitsToFloat(0x7f800000u);  // +infinity
    uint nearest = NO_TRIANGLE;
    uint end = bucket_offsets[s.bucket + 1u];
    for (uint k = bucket_offsets[s.bucket]; k < end; ++k) {
        uint t = bucket_triangles[k];
        if (u_mode == 0u) {
            if (triangle_object[t] == owner_object) {
                continue;
            }
        } else {
            if (t == owner) {
                continue;
            }
            uint t0 = triangle_indices[3u * t];
            uint t1 = triangle_indices[3u * t + 1u];
            uint t2 = triangle_indices[3u * t + 2u];
            if (t0 == o0 || t0 == o1 || t0 == o2 || t1 == o0 || t1 == o1 || t1 == o2 ||
                t2 == o0 || t2 == o1 || t2 == o2) {
                continue;  // shares a vertex with the owner: its 1-ring
            }
        }
        precise float d2 =
            point_triangle_distance_squared(p, corner(t, 0u), corner(t, 1u), corner(t, 2u));
        if (d2 <= r2 && d2 < best) {
            best = d2;
            nearest = t;
        }
    }
    out_distance[i] = nearest == NO_TRIANGLE ? best : sqrt(best);
    out_nearest[i] = nearest;
}
)glsl";

}  // namespace

std::string dvd_shader_source() {
    std::string source = SOURCE;
    const std::string key = "LOCAL_SIZE";
    source.replace(source.find(key), key.size(), std::to_string(DVD_LOCAL_SIZE));
    return source;
}

}  // namespace proxima::gpu
