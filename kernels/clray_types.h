// The host/device contract. Every struct here has a numpy twin of the same name in
// clray/device/layout.py, field for field; tests/test_layout.py checks sizeof and offsetof on the
// device. Buffers hold float32 in every build; REAL (float or double) is only the arithmetic.
// No float3 in buffers: float4 with a scalar or padding in .w, and every struct is a multiple
// of 16 bytes.
#ifndef CLRAY_TYPES_H
#define CLRAY_TYPES_H

// A BVH primitive reference: type in the top bits, index into that type's array below. The
// type codes also order ties in t (see docs/rendering.md), planes (not in the BVH) first.
#define PRIM_PLANE 0
#define PRIM_SPHERE 1
#define PRIM_BOX 2
#define PRIM_CYLINDER 3
#define PRIM_CONE 4
#define PRIM_TRIANGLE 5
#define PRIM_INSTANCE 6
#define PRIM_TORUS 7
#define PRIM_TYPE_SHIFT 28
#define PRIM_INDEX_MASK 0x0FFFFFFF

#define LIGHT_POINT 0
#define LIGHT_DIRECTIONAL 1
#define LIGHT_SPOT 2
#define LIGHT_RECT 3
#define LIGHT_DISC 4
#define LIGHT_SPHERE 5
#define LIGHT_TRIANGLE 6  // an emissive mesh face
#define LIGHT_MESH 7      // many emissive faces of a mesh, a sample picking one (lights.h)

#define TEXTURE_NONE (-1)
#define TEXTURE_CHECKER 0
#define TEXTURE_IMAGE 1

typedef struct {
    float4 center_radius;  // xyz centre, w radius
    int material;
    int pad0, pad1, pad2;
} Sphere;

typedef struct {
    float4 point;   // w: u of `point` in the plane's texture frame (the host moves the point)
    float4 normal;  // unit; w: v of `point`
    int material;
    int pad0, pad1, pad2;
} Plane;

typedef struct {
    float4 lo;  // w unused
    float4 hi;  // w unused
    int material;
    int pad0, pad1, pad2;
} Box;

typedef struct {
    float4 base_radius;  // xyz centre of the bottom cap, w radius
    float4 axis_height;  // xyz unit axis, w height
    int material;
    int capped;
    int pad0, pad1;
} Cylinder;

typedef struct {
    float4 apex_tan;     // xyz apex, w tan(half-angle)
    float4 axis_height;  // xyz unit axis from the apex to the base, w height
    int material;
    int capped;
    int pad0, pad1;
} Cone;

typedef struct {
    float4 centre_major;  // xyz centre, w major radius (the circle's)
    float4 axis_minor;    // xyz unit axis, w minor radius (the tube's), 0 < minor <= major
    int material;
    int pad0, pad1, pad2;
} Torus;

// Triangle.material: the material index in the low 24 bits, and these flags above it.
#define TRIANGLE_MATERIAL_MASK 0x00FFFFFF
#define TRIANGLE_SMOOTH (1 << 24)  // blend the vertex normals
#define TRIANGLE_UV (1 << 25)      // blend the vertex texture coordinates
#define TRIANGLE_COLOR (1 << 26)   // blend the vertex colours (times the material's colour)

// One a triangle slot, in prim_refs' order (a hit's part is its slot), not in the scene's
// order: the hits of neighbouring rays then read neighbouring records (clray/device/pack.py).
typedef struct {
    int v0, v1, v2;  // indices into the vertex arrays (normals, uvs, colors)
    int material;    // index and flags, see above
} Triangle;

typedef struct {
    float4 color;  // w unused
    float ambient, diffuse, specular, shininess;
    float reflect, transmit, ior;
    int texture;  // index into the texture array, or TEXTURE_NONE
    int fresnel;  // 1: transmit is split by the Fresnel reflectance (HAS_FRESNEL builds)
    int pad0, pad1, pad2;
    float4 emission;  // radiance the surface emits, w unused
} Material;

typedef struct {
    float4 color2;  // checker's second colour, w unused
    float size;     // checker cell size
    float repeat_u, repeat_v, blend;
    int kind;          // TEXTURE_CHECKER or TEXTURE_IMAGE
    int texel_offset;  // first texel of this image in the texel array
    int width, height;
} Texture;

typedef struct {
    // Point and spot: the position. Directional: the travel direction. Rect and triangle: a
    // corner. Disc and sphere: the centre, w the radius.
    float4 position;
    float4 color;        // area lights: the radiance, w the emitting area (rect, disc, triangle)
    float4 attenuation;  // point and spot: constant, linear, quadratic, w unused
    // Spot: axis_u the unit direction, w vers(angle); axis_v.w vers(inner_angle), with
    // vers = 1 - cos, the versine (kernels/lights.h, spot_factor).
    float4 axis_u;  // rect, triangle: edge u; disc: unit normal
    float4 axis_v;  // rect, triangle: edge v
    int kind;       // LIGHT_*
    // Mesh: its faces' records (triangle lights after the n_lights that the shading loops take),
    // pad0 the first's index and pad1 how many; a face's pad0 its pick threshold, a uint.
    int pad0, pad1, pad2;
} Light;

typedef struct {
    float4 position;  // the eye, in the packed (camera-relative) frame
    float4 forward;   // unit
    float4 right;     // unit right times half the image-plane width at distance 1
    float4 up;        // unit up times half the image-plane height at distance 1
    float4 world;     // the packed frame's origin in world space: solid textures need world p
    // Thin lens (HAS_THIN_LENS): unit right and up times the lens radius; w of lens_u is one
    // over the focus distance. Orthographic cameras (HAS_ORTHOGRAPHIC) read right and up as the
    // view's half extents in world units.
    float4 lens_u;
    float4 lens_v;
} Camera;

typedef struct {
    float4 background;  // the colour, or the gradient's bottom (straight down)
    float4 ambient;  // the scene's global ambient light colour
    int width, height, spp, max_depth;
    uint seed;
    int n_planes, n_lights, n_nodes;  // n_nodes: BvhNode records, 0 when the BVH is empty
    float min_weight;  // secondary rays of a smaller weight (largest channel) are not traced
    // The equirectangular environment (HAS_BACKGROUND_IMAGE): its first texel in the texel
    // array and its size.
    int background_texels, background_width, background_height;
    float4 background_top;  // the gradient's colour straight up (HAS_BACKGROUND_GRADIENT)
} Params;

// A wide BVH node (clray/accel/wide.py): up to BVH_WIDTH (4 or 8, a build option) children with
// their bounds axis by axis, so one vector slab test covers them all. child[k] is an inner
// child's node index, or a leaf's first slot in prim_refs, or an instance's index, or -1 for an
// empty slot; count[k] is 0 for an inner child, a leaf's section sizes (below) for a leaf, and
// ENTER_INSTANCE (below) for an instance, whose box is then its lane's. Bounds are rounded
// outwards to float32 on the host, so they hold in the double build too. Only builds that set
// BVH_WIDTH have it (the device BVH build does not).
#ifdef BVH_WIDTH
typedef struct {
    float lo_x[BVH_WIDTH], lo_y[BVH_WIDTH], lo_z[BVH_WIDTH];
    float hi_x[BVH_WIDTH], hi_y[BVH_WIDTH], hi_z[BVH_WIDTH];
    int child[BVH_WIDTH];
    int count[BVH_WIDTH];
} BvhNode;
#endif

// The binary tree that the BVH build makes (clray/accel/bvh.py on the host, kernels/bvh_build.cl
// on the device) and clray/accel/wide.py collapses: for an inner node (count 0) `first` is its
// right child (its left child is the next node; in the device build's own layout, `first` is its
// left child and the right one follows it), for a leaf its first slot in the build's order.
typedef struct {
    float lo[3];
    int first;
    float hi[3];
    int count;
} BinaryNode;

// The device build's primitive: its bounds rounded outwards and its centroid, vectors so that it
// is three aligned loads; the primitive's index rides in the centroid's w, its bin of the moment
// in hi.w (kernels/bvh_build.cl, add_to_bin).
typedef struct {
    float4 lo, hi, c;
} BuildPrim;

// A subtree the device build has still to split: its bounds and centroid bounds, its
// primitives and its node's slot (then padding, as the float4s align it anyway).
typedef struct {
    float4 lo, hi, clo, chi;
    int start, count, pos, pad0;
} BuildTask;

// A leaf's triangles sit first in its prim_refs slots, in packets of PACKET_WIDTH (padded with
// -1), then its spheres likewise, then its other primitives. Leaves start at multiples of
// PACKET_WIDTH, so packets[slot / PACKET_WIDTH] holds the shapes of slots slot .. slot + 3. A
// leaf's count: triangle packets << LEAF_TRIANGLE_SHIFT | sphere packets << LEAF_SPHERE_SHIFT |
// others.
#define PACKET_WIDTH 4
#define LEAF_TRIANGLE_SHIFT 16
#define LEAF_SPHERE_SHIFT 8
#define LEAF_FIELD_MASK 0xFF

typedef struct {
    float x0[4], y0[4], z0[4];
    float x1[4], y1[4], z1[4];
    float x2[4], y2[4], z2[4];
} TrianglePacket;

typedef struct {
    float x[4], y[4], z[4], radius[4];
} SpherePacket;

// A group of primitives placed by an affine transform (HAS_INSTANCES). The group's primitives
// sit in the same arrays as the scene's, in the group's own frame, under their own BVH (its root
// node `root`). Rows of the 3x4 matrix [L | t]: x -> L x + t. to_object maps the packed
// (camera-relative) frame to the group's; the way back is its inverse, computed where a hit is
// shaded (kernels/surface.h: instance_to_world). Its bounds in the packed frame are its lane's
// in the scene BVH's node (or, in a leaf beside other primitives, not kept: the group's root
// node culls as they would). 64 bytes.
typedef struct {
    float4 to_object[3];
    int root;
    int material;  // replaces every material of the group, or -1
    int pad0, pad1;
} Instance;

// Traversal-stack entries and node lanes that are not a node or a leaf (kernels/bvh.h), told by
// their count: enter instance `child` (a lane of the scene BVH's node, or a ref in its leaf),
// and go back to the scene's ray.
#define ENTER_INSTANCE (-1)
#define LEAVE_INSTANCE (-2)

#endif
