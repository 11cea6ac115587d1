// Tori (HAS_TORI): the points at distance `minor` from a circle of radius `major` about an axis.
// The textbook ray-torus quartic, (|p|^2 + R^2 - r^2)^2 = 4 R^2 rho^2 with the ray's origin
// anywhere, loses a thin torus in float: at r/R = 1e-4, r^2 is below R^2's rounding and the
// quartic describes the bare circle (missing pixels), and far origins cancel its coefficients
// (acne). Here the ray is first clipped to the shell around the torus (the slab |z| <= r and the
// annulus R - r <= rho <= R + r), and each piece of the shell gets a quartic of its own in a frame
// on the circle next to it:
//   P(e) = x^2 + z^2 - r^2 + (x / R) m + m^2 / (4 R^2),  m = |e|^2 - r^2,
// where e = (x, y, z) is the point relative to the circle point R n (x along n, y along the
// circle, z along the axis). P is the textbook quartic divided by 4 R^2, exactly, but its terms
// are of the size of the tube (r^2) where the tube is, so no r^2 is lost. Its roots in the piece
// are found by splitting the piece where the derivatives change sign (a quadratic's roots, then
// the cubic's), so each root is bracketed by a sign change on a monotone interval and found by
// safeguarded Newton steps (Yuksel, "High-Performance Polynomial Root Finding for Graphics",
// 2022): no root is lost between an analytic solver's roundings.
#ifndef CLRAY_TORUS_H
#define CLRAY_TORUS_H

#include "real.h"
#include "clray_types.h"
#include "scene.h"
#include "hit.h"
#include "ray.h"
#include "shape.h"

#if HAS_TORI
// The most crossings a line has with a torus.
#define TORUS_ROOTS 4

// Horner's value and derivative of c[0] + c[1] x + ... + c[degree] x^degree.
static inline REAL poly_value(const REAL* c, int degree, REAL x, REAL* slope) {
    REAL v = c[degree], dv = (REAL)0;
    for (int k = degree - 1; k >= 0; --k) {
        dv = dv * x + v;
        v = v * x + c[k];
    }
    *slope = dv;
    return v;
}

// The root of c in [a, b], where c is monotone and changes sign (fa: its value at a): Newton
// steps while they stay inside the bracket, bisection otherwise, until the bracket is a few
// roundings wide. 100 steps bound the loop: bisection alone narrows any bracket to a rounding
// in the double build within them.
static inline REAL monotone_root(const REAL* c, int degree, REAL a, REAL b, REAL fa) {
    REAL x = REAL_C(0.5) * (a + b);
    for (int i = 0; i < 100; ++i) {
        REAL slope, fx = poly_value(c, degree, x, &slope);
        if (fx == (REAL)0) return x;
        if ((fx < (REAL)0) == (fa < (REAL)0)) {
            a = x;
        } else {
            b = x;
        }
        if (b - a <= gamma_n(2) * fmax(fabs(a), fabs(b))) break;
        REAL newton = x - fx / slope;
        x = slope != (REAL)0 && newton > a && newton < b ? newton : REAL_C(0.5) * (a + b);
    }
    return x;
}

// The points where c changes sign within ends[0] .. ends[n_ends - 1], given the roots of its
// derivative between them (ends, ascending): c is monotone between consecutive ends, so each
// sign change is bracketed by one such interval. Writes them ascending into roots and returns
// their count.
static inline int sign_changes(const REAL* c, int degree, REAL* ends, int n_ends, REAL* roots) {
    int count = 0;
    REAL slope, a = ends[0], fa = poly_value(c, degree, a, &slope);
    REAL hi = ends[n_ends - 1];
    for (int k = 1; k < n_ends; ++k) {
        REAL b = ends[k], fb = poly_value(c, degree, b, &slope);
        if (fa != (REAL)0 && fb != (REAL)0 && (fa < (REAL)0) != (fb < (REAL)0)) {
            roots[count++] = monotone_root(c, degree, a, b, fa);
        } else if (fb == (REAL)0 && b < hi) {
            roots[count++] = b;  // an exact zero at an inner end: the roots are sorted still
        }
        a = b;
        fa = fb;
    }
    return count;
}

// [lo, the roots of a derivative in (lo, hi) ascending, hi] into ends; returns their count.
static inline int split_at(REAL lo, REAL hi, const REAL* inner, int n, REAL* ends) {
    ends[0] = lo;
    for (int k = 0; k < n; ++k) ends[k + 1] = inner[k];
    ends[n + 1] = hi;
    return n + 2;
}

// The sign changes of the quartic c within [lo, hi], ascending, into roots; returns their count.
// The derivatives' roots split [lo, hi] into monotone pieces, degree by degree: the third
// derivative's (linear) root, then the second derivative's roots, then the first's. Each stage
// is written out (no pointer chosen at run time between the polynomials): Intel's CPU compiler,
// vectorising work-items, lost every crossing where one loop picked its arrays by pointer.
static inline int quartic_roots_in(const REAL* c, REAL lo, REAL hi, REAL* roots) {
    REAL d1[4], d2[3];
    for (int k = 0; k < 4; ++k) d1[k] = (REAL)(k + 1) * c[k + 1];
    for (int k = 0; k < 3; ++k) d2[k] = (REAL)(k + 1) * d1[k + 1];
    REAL ends[TORUS_ROOTS + 2], inner[TORUS_ROOTS];
    int n = 0;
    // The third derivative, d2[1] + 2 d2[2] x: its one root.
    REAL d3_0 = d2[1], d3_1 = (REAL)2 * d2[2];
    if (d3_1 != (REAL)0) {
        REAL x = -d3_0 / d3_1;
        if (x > lo && x < hi) inner[n++] = x;
    }
    n = sign_changes(d2, 2, ends, split_at(lo, hi, inner, n, ends), inner);
    n = sign_changes(d1, 3, ends, split_at(lo, hi, inner, n, ends), inner);
    return sign_changes(c, 4, ends, split_at(lo, hi, inner, n, ends), roots);
}

// The torus's local quartic along the ray e(sg) = e0 + sg u (u a unit vector) in the frame of
// the circle point nearest e0 (x0 along that point's radial n, no component along the circle, z0
// along the axis; ux, uz: u along n and the axis; |u| = 1 gives m's leading term): the
// coefficients of P (above), lowest first.
static inline void local_quartic(REAL x0, REAL z0, REAL ux, REAL uz, REAL major, REAL minor,
                                 REAL* c) {
    REAL inv = (REAL)1 / major, inv2 = inv * inv;
    // x^2 + z^2 - r^2 and m = |e|^2 - r^2 as quadratics in sg: (q0, 2 h, a2) and (q0, 2 h, 1).
    REAL q0 = (x0 - minor) * (x0 + minor) + z0 * z0;
    REAL h = x0 * ux + z0 * uz;
    REAL a2 = ux * ux + uz * uz;
    c[0] = q0 + x0 * q0 * inv + REAL_C(0.25) * q0 * q0 * inv2;
    c[1] = (REAL)2 * h + ((REAL)2 * x0 * h + ux * q0) * inv + q0 * h * inv2;
    c[2] = a2 + (x0 + (REAL)2 * ux * h) * inv + (h * h + REAL_C(0.5) * q0) * inv2;
    c[3] = ux * inv + h * inv2;
    c[4] = REAL_C(0.25) * inv2;
}

// The crossings of the line o + s u (u unit, o relative to the centre) with the torus within the
// piece [lo, hi] of the shell, ascending, appended to roots (count *n).
static inline void piece_roots(REAL3 o, REAL3 u, REAL3 axis, REAL major, REAL minor, REAL lo,
                               REAL hi, REAL* roots, int* n) {
    REAL mid = REAL_C(0.5) * (lo + hi);
    REAL3 p = o + mid * u;
    REAL z0 = dot(p, axis);
    REAL3 radial = p - z0 * axis;
    REAL rho = length(radial);
    REAL3 nr = radial / rho, spare;
    if (!(rho > (REAL)0)) frame(axis, &nr, &spare);  // on the axis: any radial will do
    REAL c[5];
    local_quartic(rho - major, z0, dot(u, nr), dot(u, axis), major, minor, c);
    REAL found[TORUS_ROOTS];
    int count = quartic_roots_in(c, lo - mid, hi - mid, found);
    for (int k = 0; k < count && *n < TORUS_ROOTS; ++k) roots[(*n)++] = mid + found[k];
}

// The pieces of the line o + s u within the torus's shell: the slab |z| <= minor intersected
// with the annulus major - minor <= rho <= major + minor, each widened by a rounding bound so a
// crossing on the shell's boundary (the torus touches it along circles) stays inside. Writes at
// most two [lo, hi] pairs; returns their count.
static inline int shell_pieces(REAL3 o, REAL3 u, REAL3 axis, REAL major, REAL minor, REAL* lo,
                               REAL* hi) {
    REAL oa = dot(o, axis), ua = dot(u, axis);
    REAL3 op = o - oa * axis, up = u - ua * axis;
    REAL tol = gamma_n(16) * (max_abs3(o) + major + minor);
    REAL s0 = -REAL_INF, s1 = REAL_INF;
    if (ua != (REAL)0) {
        REAL a = (-minor - oa) / ua, b = (minor - oa) / ua;
        s0 = fmin(a, b) - tol / fabs(ua);
        s1 = fmax(a, b) + tol / fabs(ua);
    } else if (fabs(oa) > minor + tol) {
        return 0;
    }
    // rho(s)^2 = A s^2 + 2 B s + C; the cylinders rho = R +- r by the cylinder's stable roots.
    REAL A = dot(up, up), B = dot(op, up);
    REAL lop = length(op);
    REAL outer = major + minor + tol, inner = major - minor - tol;
    if (!(A > (REAL)0)) {
        // Along the axis: rho is constant, in the shell or not.
        if (lop > outer || lop < inner) return 0;
        lo[0] = s0;
        hi[0] = s1;
        return 1;
    }
    REAL3 l = op - (B / A) * up;
    REAL ll = length(l);
    REAL o0 = (REAL)0, o1 = (REAL)0, i0 = (REAL)0, i1 = (REAL)0;
    if (!quadratic_roots(A, B, (lop - outer) * (lop + outer), A * (outer - ll) * (outer + ll),
                         &o0, &o1)) {
        return 0;
    }
    bool hole = inner > (REAL)0 &&
                quadratic_roots(A, B, (lop - inner) * (lop + inner),
                                A * (inner - ll) * (inner + ll), &i0, &i1);
    int n = 0;
    REAL a0 = fmax(o0, s0), b0 = fmin(hole ? i0 : o1, s1);
    if (a0 < b0) {
        lo[n] = a0;
        hi[n++] = b0;
    }
    if (hole) {
        REAL a1 = fmax(i1, s0), b1 = fmin(o1, s1);
        if (a1 < b1) {
            lo[n] = a1;
            hi[n++] = b1;
        }
    }
    return n;
}

// Every crossing of the ray with the torus at t > 0, ascending, into t (REAL_INF past the
// last); returns their count. The ray's direction is normalised for the root finding (s: length
// along it) and the roots mapped back to the ray's t.
// The root finding works in units of the torus: lengths divided by 2^e, the power of two at or
// below the major radius. The local quartic squares q0 (about r^2) and has 1 / R^2 for its
// leading term, so in world units float32 overflows for rings past about 1e10 (r^4 over 3e38:
// no crossing is found) and goes denormal for rings near 1e-11 (r^4 / R^2 under 1e-38: wrong
// crossings); in the torus's units every coefficient is of order 1 at any size. Scaling by a
// power of two is exact, and every step below is homogeneous in length (the shell's
// rounding bound, the brackets' widths), so where world units neither overflow nor underflow
// the crossings are theirs bit for bit.
static inline int torus_crossings(const __global Torus* tr, const Ray* r, REAL* t) {
    for (int k = 0; k < TORUS_ROOTS; ++k) t[k] = REAL_INF;
    REAL len = length(r->d);
    REAL major = TO_REAL(tr->centre_major.w), minor = TO_REAL(tr->axis_minor.w);
    // exponent_of needs a positive normal major: 0 has no exponent (the loader keeps lengths
    // at least 1e-30).
    if (!(len > (REAL)0) || !(major > (REAL)0)) return 0;
    int e = exponent_of(major);
    // 2^-e and 2^e lie in float's normal range (|e| <= 100 for the loader's lengths), so a
    // product with either is ldexp's, exactly (real.h). A vector is scaled by the product, not
    // by ldexp: Oclgrind 21.10's ldexp of a vector applies the scalar exponent to its first
    // lane only.
    REAL unit = power_of_two(-e);
    major *= unit;
    minor *= unit;
    // The stored float32 axis is unit only to float rounding; the local quartic takes u and the
    // axis as unit to the build's precision.
    REAL3 u = r->d / len, axis = normalize(TO_REAL3(tr->axis_minor));
    REAL3 o = (r->o - TO_REAL3(tr->centre_major)) * unit;
    REAL lo[2], hi[2];
    int pieces = shell_pieces(o, u, axis, major, minor, lo, hi);
    REAL roots[TORUS_ROOTS];
    int n = 0;
    for (int k = 0; k < pieces; ++k) {
        if (hi[k] > (REAL)0) piece_roots(o, u, axis, major, minor, fmax(lo[k], (REAL)0), hi[k],
                                         roots, &n);
    }
    int count = 0;
    for (int k = 0; k < n; ++k) {
        REAL tk = roots[k] * power_of_two(e) / len;
        if (tk > (REAL)0) t[count++] = tk;
    }
    return count;
}

// A torus's first two crossings ahead, as every shape reports them (shape.h): closest-hit takes
// the first. Shadow rays, which count every crossing, take all of them (bvh.h:
// filter_torus_crossings).
static OUT_OF_LINE Crossings intersect_torus(const __global Torus* tr, const Ray* r) {
    REAL t[TORUS_ROOTS];
    torus_crossings(tr, r, t);
    Crossings c = no_crossings();
    c.t[0] = t[0];
    c.t[1] = t[1];
    return c;
}

// shape_surface's part for a torus: *p, the ray's point on entry, re-projected onto the tube
// along its normal (from the nearest point of the circle); its outward normal, error bound
// (gamma: the bound's factor), material and, where want_uv, (u, v): around the axis and around
// the tube (0 and 1 on the inner equator, 0.5 on the outer).
HOT void torus_surface(const __global Torus* tr, bool want_uv, REAL gamma, REAL3* p,
                       Surface* sf) {
    REAL3 c = TO_REAL3(tr->centre_major), axis = normalize(TO_REAL3(tr->axis_minor));
    REAL major = TO_REAL(tr->centre_major.w), minor = TO_REAL(tr->axis_minor.w);
    REAL3 q = *p - c;
    REAL h = dot(q, axis);
    REAL3 radial = q - h * axis, e1, e2;
    REAL rho = length(radial);
    // Decided on the stored axis: the float and double builds normalise it differently.
    frame_by(axis, tr->axis_minor.x, &e1, &e2);
    REAL3 nr = rho > (REAL)0 ? radial / rho : e1;  // on the axis (minor = major): any radial
    REAL3 n = safe_normalize(q - major * nr);
    *p = c + major * nr + minor * n;
    sf->n_g = n;
    sf->err = gamma * (max_abs3(*p) + max_abs3(c) + major + minor);
    if (want_uv) {
        sf->uv = (REAL2)(angle_u(dot(q, e2), dot(q, e1)), angle_u(dot(n, axis), dot(n, nr)));
    }
    sf->material = tr->material;
}
#endif

#endif
