// REAL is the arithmetic type of the whole kernel: float by default, double with -DUSE_DOUBLE.
// Buffers stay float32 in both builds; values are widened on load, so the double build is the
// same algorithm on the same inputs with more bits.
#ifndef CLRAY_REAL_H
#define CLRAY_REAL_H

#ifdef USE_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double REAL;
typedef double2 REAL2;
typedef double3 REAL3;
typedef double4 REAL4;
typedef long4 MASK4;  // what comparing two REAL4 gives
#define REAL_EPSILON DBL_EPSILON
#define TO_REAL3(v) convert_double3((v).xyz)
#define TO_REAL2(v) convert_double2(v)
#define TO_REAL4(v) convert_double4(v)
#define TO_REAL(x) ((double)(x))
#else
#ifdef cl_khr_fp64
// The float build decides exact-zero triangle edge functions in double where it can.
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif
typedef float REAL;
typedef float2 REAL2;
typedef float3 REAL3;
typedef float4 REAL4;
typedef int4 MASK4;
#define REAL_EPSILON FLT_EPSILON
#define TO_REAL3(v) ((v).xyz)
#define TO_REAL2(v) (v)
#define TO_REAL4(v) (v)
#define TO_REAL(x) (x)
#endif

// REAL_C(x): the floating literal x as a constant of REAL's precision, x with an f suffix in
// the float build and plain in the double build (C's UINT64_C, for REAL). A plain literal is a
// double constant, even cast to float, and a device without cl_khr_fp64 must refuse it or round
// it to float with a warning ("double precision constant requires cl_khr_fp64"), tens a build
// (tests/test_gpu_targets.py builds every configuration without fp64, warnings as errors). x
// must be a floating literal (with a point or an exponent): an f pasted onto an integer is no
// literal. Every constant so written is a float exactly as its double was cast to one, so the
// float build's arithmetic is unchanged (benchmarks/image_hashes.py: every image the same).
#ifdef USE_DOUBLE
#define REAL_C(x) x
#else
#define REAL_C(x) x##f
#endif

// Vectors wider than the target's (a sample packet's 16 floats, or 8 doubles, on AVX2; a wide
// node's 8 doubles) are passed between functions in a way an AVX-512 build would pass
// otherwise, and clang warns so at every such function (-Wpsabi): hundreds of warnings, whose
// count PoCL prints to the terminal at a render's first build. Every function is built into
// the same program, so the calling convention is the compiler's own business. Only where the
// compiler knows the warning: NVIDIA's OpenCL compiler (driver 580) warned of the unknown
// group itself and wrote "1 warning generated." to the terminal at every build.
#if defined(__clang__) && defined(__has_warning)
#if __has_warning("-Wpsabi")
#pragma clang diagnostic ignored "-Wpsabi"
#endif
#endif

// The traversal and intersection helpers run once per node or primitive test: a call that is
// not inlined costs as much as the test (PoCL does not inline everything marked inline).
// Oclgrind builds with -DHOT=inline (clray/device/program.py, device_build_options).
// Static too (issue 42, the cold build): clang runs its -O2 pipeline at clBuildProgram (the
// OpenCL default; PoCL's kernel compiler optimises the kernel again at its first launch), and
// an external HOT function was kept, optimised and written to PoCL's program.bc beside every
// copy inlined into its callers; a static one is dropped once inlined: textured's program.bc
// went from 415 to 156 KB and clang's share of clBuildProgram ran 14 % fewer instructions
// (docs/acceleration.md, The cold build's optimiser).
#ifndef HOT
#define HOT static inline __attribute__((always_inline))
#endif

// STAGE marks the functions that are the renderer's stages: the camera ray, the closest hit,
// the shading point, a light's shadow ray and term, the shadow ray's transmission, the ray
// set-up, and the sample packets' walks. They inline as HOT ones do; the stage-profiling build
// (-DSTAGE_PROFILE=1, benchmarks/stages.py) keeps each a function of its own, so a profiler
// can say how many instructions each stage takes. The sample packets' walks (packet_closest,
// packet_transmission) are OUT_OF_LINE in every build (issue 42: the cold build). The
// single-ray closest_hit and transmission out of line cut spheres' cold build 2.0 -> 1.3 CPU-s
// but made its 1-spp render 14 % slower (benchmarks/compare.py): they stay STAGEs.
#if defined(STAGE_PROFILE) && STAGE_PROFILE
#define STAGE __attribute__((noinline))
#else
#define STAGE HOT
#endif

// OUT_OF_LINE keeps a function that runs once for many rays, and holds their state in large
// private arrays, out of its caller: inlined, the sample packet's tracing made PoCL compile
// the kernel's ray-by-ray ray tree around its registers and arrays, and the packet build ran
// 5 % more instructions a sample and took 10 % longer (docs/acceleration.md). It also keeps
// out of line the helpers that PoCL left there while they were C99's plain inline (which
// defines nothing a call can reach, 2d03750): sample_position's jitter (jittered_position),
// lens_sample, light_square, sample_area_light, image_texel, intersect_cylinder and
// intersect_cone, out of line in every build that had them. Made static inline they were
// inlined: sample_position alone made the spheres' single-ray kernel run 2.9 % more
// instructions (docs/acceleration.md, Kernels by concept).
#define OUT_OF_LINE __attribute__((noinline))

// A squared length whose square root needs no scaling against overflow and underflow (the
// twins' range, below, and the fused builtins' of the accuracy build): M is int for a scalar
// (1 or 0) and a lane mask for vectors, as their comparisons give.
#define DEFINE_PLAIN_SQUARED_LENGTH(SPEC, T, M, NAME)                 \
    SPEC M NAME(T dd) { return (dd >= (T)REAL_C(0x1p-90)) & (dd <= (T)REAL_C(0x1p90)); }

// MATH_ULPS_OFF (+1 or -1; tests only, tests/conftest.py --opencl-ulps): sin, cos, tan, asin,
// atan2, exp2 and log2 return results off by OpenCL's error bounds for them (4, 4, 4, 4, 6, 3
// and 3 ulps, float and double alike) in that direction. The CPU drivers' are within an ulp, a
// GPU's need not be: a test that passes only with the CPU's accuracy does not show that the
// kernels hold on any OpenCL device (the first GPU run failed one, docs/gpu.md).
#if defined(MATH_ULPS_OFF) && MATH_ULPS_OFF
#ifdef cl_khr_fp64
#define MATH_ULPS_OFF_DOUBLE(DEFINITION) DEFINITION
#else
#define MATH_ULPS_OFF_DOUBLE(DEFINITION)
#endif
// WRAPPER: the wrapper's name; CALL: the builtin's call (a driver's macro for it expanded).
#define DEFINE_ULPS_OFF(T, WRAPPER, CALL, ULPS, PARAMS)                                \
    static inline __attribute__((overloadable)) T WRAPPER PARAMS {                     \
        T v = CALL;                                                                    \
        T ulp = nextafter(fabs(v), (T)INFINITY) - fabs(v);                             \
        return isfinite(v) ? v + (T)(MATH_ULPS_OFF * ULPS) * ulp : v;                 \
    }
#define DEFINE_ULPS_OFF_1(NAME, ULPS)                                                  \
    DEFINE_ULPS_OFF(float, NAME##_ulps_off, NAME(x), ULPS, (float x))                  \
    MATH_ULPS_OFF_DOUBLE(DEFINE_ULPS_OFF(double, NAME##_ulps_off, NAME(x), ULPS, (double x)))
DEFINE_ULPS_OFF_1(sin, 4)
DEFINE_ULPS_OFF_1(cos, 4)
DEFINE_ULPS_OFF_1(tan, 4)
DEFINE_ULPS_OFF_1(asin, 4)
DEFINE_ULPS_OFF_1(exp2, 3)
DEFINE_ULPS_OFF_1(log2, 3)
DEFINE_ULPS_OFF(float, atan2_ulps_off, atan2(y, x), 6, (float y, float x))
MATH_ULPS_OFF_DOUBLE(DEFINE_ULPS_OFF(double, atan2_ulps_off, atan2(y, x), 6, (double y, double x)))
// A driver may define the builtins as macros (PoCL does): the wrappers above took them as they
// were; from here on the names are the wrappers'.
#undef sin
#undef cos
#undef tan
#undef asin
#undef atan2
#undef exp2
#undef log2
#define sin(x) sin_ulps_off(x)
#define cos(x) cos_ulps_off(x)
#define tan(x) tan_ulps_off(x)
#define asin(x) asin_ulps_off(x)
#define atan2(y, x) atan2_ulps_off(y, x)
#define exp2(x) exp2_ulps_off(x)
#define log2(x) log2_ulps_off(x)
// The geometric builtins have no error bound in OpenCL, and "can be implemented using
// contractions": here dot() fuses its products (last to first up, first to last down; the CPU
// drivers' round each), and length() and normalize() take that dot product (normalize()
// dividing by the length where the CPU drivers multiply by rsqrt). Where the squared length is
// outside [2^-90, 2^90] they are the driver's, which scales against overflow and underflow.
// mix(), a common function that may be "implemented using contractions" too, fuses its product
// with the sum (the CPU drivers round the product first).
#define DEFINE_FUSED_DOT(T, T2, T3, T4)                                                 \
    static inline __attribute__((overloadable)) T3 mix_fused(T3 x, T3 y, T a) {        \
        return fma(y - x, (T3)(a), x);                                                 \
    }                                                                                  \
    static inline __attribute__((overloadable)) T dot_fused(T2 a, T2 b) {              \
        return MATH_ULPS_OFF > 0 ? fma(a.y, b.y, a.x * b.x) : fma(a.x, b.x, a.y * b.y);  \
    }                                                                                  \
    static inline __attribute__((overloadable)) T dot_fused(T3 a, T3 b) {              \
        return MATH_ULPS_OFF > 0 ? fma(a.z, b.z, fma(a.y, b.y, a.x * b.x))            \
                                 : fma(a.x, b.x, fma(a.y, b.y, a.z * b.z));           \
    }                                                                                  \
    static inline __attribute__((overloadable)) T dot_fused(T4 a, T4 b) {              \
        return MATH_ULPS_OFF > 0 ? fma(a.w, b.w, dot_fused(a.xyz, b.xyz))              \
                                 : fma(a.x, b.x, fma(a.y, b.y, fma(a.z, b.z, a.w * b.w))); \
    }                                                                                  \
    DEFINE_PLAIN_SQUARED_LENGTH(static inline __attribute__((overloadable)), T, int,  \
                                plain_fused)                                           \
    static inline __attribute__((overloadable)) T length_fused(T3 v) {                 \
        T dd = dot_fused(v, v);                                                        \
        return plain_fused(dd) ? sqrt(dd) : length(v);                                 \
    }                                                                                  \
    static inline __attribute__((overloadable)) T3 normalize_fused(T3 v) {             \
        T dd = dot_fused(v, v);                                                        \
        return plain_fused(dd) ? v / sqrt(dd) : normalize(v);                          \
    }
DEFINE_FUSED_DOT(float, float2, float3, float4)
MATH_ULPS_OFF_DOUBLE(DEFINE_FUSED_DOT(double, double2, double3, double4))
#undef dot
#undef length
#undef normalize
#undef mix
#define mix(x, y, a) mix_fused(x, y, a)
#define dot(a, b) dot_fused(a, b)
#define length(v) length_fused(v)
#define normalize(v) normalize_fused(v)
#endif

#define REAL_INF ((REAL)INFINITY)
#define PI_R REAL_C(3.14159265358979323846)

// Powers of two read from and written into REAL's bits: exponent_of(x) is floor(log2(x)), as
// ilogb gives it, for a positive normal x; power_of_two(e) is 2^e for e in the normal range
// (-126 to 127 in float, -1022 to 1023 in double). In PoCL's build ilogb and ldexp are calls
// into its library, and the scale-free torus's two of each cost tori 7.8 % more instructions
// (docs/rendering.md, Design history); these are a shift and an add. Outside those ranges they
// return wrong numbers, not ilogb's or ldexp's (zero, a subnormal, a negative, an infinite or
// a NaN x; e past the normal range): the callers rule them out. The loader keeps lengths and a
// transform's stretches within [1e-30, 1e30], so their exponents and the callers' |e| stay
// below about 100.
// x * power_of_two(e) is ldexp(x, e) bit for bit: a product is correctly rounded (OpenCL
// allows 0 ulp for it), so it is x 2^e exactly where that is representable and rounded as
// ldexp rounds it where it is not, as long as the factor 2^e is itself a normal REAL.
#ifdef USE_DOUBLE
static inline int exponent_of(REAL x) { return (int)(as_long(x) >> 52) - 1023; }
static inline REAL power_of_two(int e) { return as_double((long)(e + 1023) << 52); }
#else
static inline int exponent_of(REAL x) { return (as_int(x) >> 23) - 127; }
static inline REAL power_of_two(int e) { return as_float((e + 127) << 23); }
#endif

// pbrt's bound on n chained roundings: gamma(n) = n u / (1 - n u), u the unit roundoff.
static inline REAL gamma_of(int n, REAL u) {
    return (REAL)n * u / ((REAL)1 - (REAL)n * u);
}

static inline REAL gamma_n(int n) { return gamma_of(n, REAL_EPSILON * REAL_C(0.5)); }

// The same bound counted in float32 roundings in either build: for values the buffers hold in
// float32 (a plane, a light's position), which the double build widens but cannot sharpen.
// In the float build it is gamma_n, operation for operation.
static inline REAL gamma_f32(int n) { return gamma_of(n, (REAL)FLT_EPSILON * REAL_C(0.5)); }

static inline REAL max_abs3(REAL3 v) {
    REAL3 a = fabs(v);
    return fmax(a.x, fmax(a.y, a.z));
}

static inline REAL max_comp3(REAL3 v) { return fmax(v.x, fmax(v.y, v.z)); }

static inline REAL comp3(REAL3 v, int k) { return k == 0 ? v.x : (k == 1 ? v.y : v.z); }


// LESSER and GREATER are compare-selects, one instruction on x86 where fmin and fmax take
// three or four for their NaN rules: for numbers that cannot be NaN, or where a NaN must
// give zero (GREATER(x, 0) is fmax(x, 0) for every x but -0, whose square root is zero too).
// Scalars and vectors alike (a vector's comparison selects lane by lane).
#define LESSER(a, b) ((a) < (b) ? (a) : (b))
#define GREATER(a, b) ((a) > (b) ? (a) : (b))

// Twins: a formula that one ray and a packet's lanes (a leaf packet's four triangles, a sample
// packet's rays) both need is written once, as a DEFINE_ macro that defines it for a type T,
// REAL or a vector of REALs: OpenCL's vector types take the same operators, builtins, selects
// (a ? b : c lane by lane) and comparisons (giving M: int for REAL, MASK4 or MASKP for vectors),
// so each lane gets the scalar's arithmetic in the scalar's order, and the same rounding, as
// tests/test_packets.py checks. Each definition is the code that each of the twins was before
// (docs/acceleration.md, Twins), so it costs no instruction.

// The geometry that a ray and its lane-wise twins share: d . e, length, normalize and cross,
// written out. OpenCL leaves the builtins' rounding to the device (its geometric functions
// "can be implemented using contractions"): PoCL's and Intel's round each product and add left
// to right, another device may fuse them, and the twins then part by an ulp. Here each product
// is a statement of its own (OpenCL C contracts a * b + c into an fma only within one
// expression), so both twins round as the CPU drivers' builtins do, on any device
// (tests/test_packets.py, built with --opencl-ulps, where the builtins fuse). Where a squared
// length is outside [2^-90, 2^90] the builtins scale against overflow and underflow: the
// single ray takes them there, and the lane-wise twins leave such lanes to it.
#define DEFINE_DOT(SPEC, T, NAME)                                    \
    SPEC T NAME(T ax, T ay, T az, T bx, T by, T bz) {                \
        T xx = ax * bx;                                              \
        T yy = ay * by;                                              \
        T zz = az * bz;                                              \
        T xy = xx + yy;                                              \
        return xy + zz;                                              \
    }
DEFINE_DOT(static inline, REAL, dot_of)

static inline REAL dot3(REAL3 a, REAL3 b) { return dot_of(a.x, a.y, a.z, b.x, b.y, b.z); }

// The twins' range (DEFINE_PLAIN_SQUARED_LENGTH, above; the lanes' in lanes.h).
DEFINE_PLAIN_SQUARED_LENGTH(static inline, REAL, int, plain_squared_length)

static inline REAL length3(REAL3 v) {
    REAL dd = dot3(v, v);
    return plain_squared_length(dd) ? sqrt(dd) : length(v);
}

// Divided by the square root, not multiplied by rsqrt as the CPU drivers' normalize() is: with
// sqrt and division correctly rounded (GPU builds ask for it) every device gives the same
// direction, where OpenCL lets rsqrt be 2 ulps off, and with it that far off a glass scene cut
// by min_weight had 6 pixels off the reference, its bound 5 (tests/test_depth.py).
static inline REAL3 normalize3(REAL3 v) {
    REAL dd = dot3(v, v);
    return plain_squared_length(dd) ? v / sqrt(dd) : normalize(v);
}

static inline REAL3 cross3(REAL3 a, REAL3 b) {
    REAL3 ab = a.yzx * b.zxy;
    REAL3 ba = a.zxy * b.yzx;
    return ab - ba;
}

// Normalise, leaving a zero vector zero instead of making NaN.
static inline REAL3 safe_normalize(REAL3 v) {
    REAL len = length3(v);
    return len > (REAL)0 ? v / len : v;
}

// a*b - c*d without catastrophic cancellation (Kahan's algorithm with FMA), lane by lane.
#define DEFINE_DIFFERENCE_OF_PRODUCTS(SPEC, T, NAME) \
    SPEC T NAME(T a, T b, T c, T d) {                \
        T cd = c * d;                                \
        T err = fma(-c, d, cd);                      \
        T dop = fma(a, b, -cd);                      \
        return dop + err;                            \
    }
DEFINE_DIFFERENCE_OF_PRODUCTS(static inline, REAL, difference_of_products)
// Four triangles of a leaf packet at once.
DEFINE_DIFFERENCE_OF_PRODUCTS(HOT, REAL4, difference_of_products4)

// The OR of four lanes, as a tree over halves: fewer shuffles than OR-ing them one by one.
HOT int or_lanes4(int4 b) {
    int2 h = b.lo | b.hi;
    return h.x | h.y;
}

// Bit k set where lane k of a comparison result (each lane all ones or all zeros) is true.
// x86's movmsk gathers the lanes' sign bits in one instruction where the OR of halves takes
// six to eight (masks, shuffles and ORs, one after another), on the walk's path at every node
// and leaf; clang has no portable builtin that compiles to it. Elsewhere (GPUs; Intel's CPU
// runtime, which names no x86 target to the kernel; Oclgrind) the OR of halves.
#if defined(__clang__) && defined(__has_builtin) && defined(__AVX__) && \
    !defined(PORTABLE_REDUCTIONS)
#if __has_builtin(__builtin_ia32_movmskps) && __has_builtin(__builtin_ia32_movmskps256)
#define X86_LANE_BITS 1
#endif
#endif
#ifndef X86_LANE_BITS
#define X86_LANE_BITS 0
#endif

HOT int lane_bits4(int4 m) {
#if X86_LANE_BITS
    return __builtin_ia32_movmskps(as_float4(m));
#else
    return or_lanes4(m & (int4)(1, 2, 4, 8));
#endif
}

HOT int lane_bits8(int8 m) {
#if X86_LANE_BITS
    return __builtin_ia32_movmskps256(as_float8(m));
#else
    return or_lanes4((m.lo & (int4)(1, 2, 4, 8)) | (m.hi & (int4)(16, 32, 64, 128)));
#endif
}

// The lowest set bit's index (bits != 0); ctz is OpenCL 2.0, clz is 1.2.
HOT int lowest_bit(int bits) { return 31 - clz(bits & -bits); }

// An orthonormal pair perpendicular to unit a, the frame() of docs/rendering.md, its helper
// axis chosen by x, a's x as the float32 the scene buffers store: compared in float, so that
// the float and double builds, the host and the reference (which round to float32 too) take
// the same branch where |x| lies within float32 rounding of 0.9.
static inline void frame_by(REAL3 a, float x, REAL3* e1, REAL3* e2) {
    REAL3 h = fabs(x) < 0.9f ? (REAL3)(1, 0, 0) : (REAL3)(0, 1, 0);
    *e1 = safe_normalize(cross(a, h));
    *e2 = cross(a, *e1);
}

// frame_by() on a's own x: for an a read straight from a buffer, (float)a.x is the stored
// value in either build.
static inline void frame(REAL3 a, REAL3* e1, REAL3* e2) { frame_by(a, (float)a.x, e1, e2); }

// SERIAL_WORK_ITEMS: the driver runs a work-group's work-items one after another, a pass of a
// loop each on one CPU thread (PoCL's CPU device; Intel's CPU runtime as the render kernels ask
// it, IMPLICIT_VECTORIZATION 0), not side by side in a vector's lanes (that runtime packing
// them) or in a GPU's (the amdgcn and nvptx targets). The host sets it to 0 for every GPU
// device (program.device_build_options): a vendor's compiler need not name its target.
#ifndef SERIAL_WORK_ITEMS
#if IMPLICIT_VECTORIZATION || defined(__AMDGCN__) || defined(__NVPTX__)
#define SERIAL_WORK_ITEMS 0
#else
#define SERIAL_WORK_ITEMS 1
#endif
#endif

#endif
