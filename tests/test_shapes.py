"""The shapes' registry (clray.shapes): it names every primitive code and shape switch the
kernels have, and each shape's parts agree with one another: its scene keys with its model's
fields, its packed bounds with its float64 crossings, its placement with its crossings. The
records and codes against the device are tests/test_layout.py's (layout.STRUCTS and
layout.PRIMS come from the registry)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from clray.accel import prim_refs
from clray.device import layout
from clray.device.program import FEATURE_SWITCHES, KernelConfig, kernel_source
from clray.errors import SceneError
from clray.scene import limits as L
from clray.scene.load import scene_from_dict
from clray.shapes import SHAPE_KINDS, SHAPES
from clray.shapes.shape import Shape, similarity_scale

KERNELS = Path(__file__).resolve().parent.parent / "kernels"
# The primitives that are not shapes of the registry's kind (clray/shapes/__init__.py).
NOT_SHAPES = {"PRIM_PLANE": prim_refs.PRIM_PLANE, "PRIM_TRIANGLE": prim_refs.PRIM_TRIANGLE,
              "PRIM_INSTANCE": prim_refs.PRIM_INSTANCE}
# One object of each shape, in the scene file's form, about the origin.
EXAMPLES = {
    "sphere": {"center": [0.3, -0.2, 0.1], "radius": 1.2},
    "box": {"min": [-1, -0.5, -0.8], "max": [0.9, 1.1, 0.6]},
    "cylinder": {"base": [0.1, -1, 0.2], "axis": [0.2, 1, -0.1], "radius": 0.7, "height": 1.8},
    "cone": {"apex": [0, 1, 0.1], "axis": [0.1, -1, 0.2], "angle": 25, "height": 1.9},
    "torus": {"center": [0.1, 0, -0.2], "axis": [0.3, 1, 0.2], "major_radius": 1.1,
              "minor_radius": 0.3},
}


def _header_prims() -> dict[str, int]:
    header = kernel_source("clray_types.h")
    return {name: int(value) for name, value in
            re.findall(r"^#define (PRIM_[A-Z]+) (\d+)$", header, flags=re.MULTILINE)}


def test_the_registry_names_every_primitive_code_of_the_kernels() -> None:
    prims = _header_prims()
    assert {"PRIM_SPHERE", "PRIM_TORUS", "PRIM_PLANE"} <= set(prims)  # the scan found them
    shapes = {shape.prim_name: shape.prim for shape in SHAPES}
    assert {**shapes, **NOT_SHAPES} == prims
    assert len(set(prims.values())) == len(prims)


def test_a_primitive_code_that_makes_negative_references_is_refused() -> None:
    # References are code << PRIM_TYPE_SHIFT | index in an int32: a code of 8 or more (or a
    # negative one) makes them negative. The registry's codes pass (checked on import).
    assert prim_refs.PRIM_CODES == 1 << (31 - prim_refs.PRIM_TYPE_SHIFT) == 8
    prim_refs.check_codes(SHAPES)
    largest = dataclasses.replace(SHAPES[-1], prim=prim_refs.PRIM_CODES - 1)
    prim_refs.check_codes((*SHAPES[:-1], largest))
    for code in (prim_refs.PRIM_CODES, -1):
        bad = dataclasses.replace(SHAPES[-1], prim=code)
        with pytest.raises(ValueError, match=rf"^{bad.prim_name} is {code}: a primitive type "
                                             r"code must be from 0 to 7 \(below 1 << \(31 - "
                                             r"PRIM_TYPE_SHIFT\)\)"):
            prim_refs.check_codes((*SHAPES[:-1], bad))


def test_each_shape_has_its_struct_buffer_and_switch_in_the_kernels() -> None:
    header, scene = kernel_source("clray_types.h"), kernel_source("scene.h")
    shapes_h = (KERNELS / "shapes.h").read_text(encoding="utf-8")
    for shape in SHAPES:
        assert re.search(rf"^}} {shape.struct};$", header, flags=re.MULTILINE), shape.kind
        assert f"X({shape.struct}, {shape.buffer})" in scene, shape.kind
        assert f"#if {shape.switch.upper()}" in shapes_h, shape.kind
        assert shape.switch in FEATURE_SWITCHES
        assert f"-D{shape.switch.upper()}=1" in KernelConfig(**{shape.switch: True}).options()


def test_the_kernels_switch_on_no_shape_the_registry_lacks() -> None:
    # shapes.h's switches over a primitive's type: every shape's, those of the primitives the
    # layers name themselves (and a triangle's vertex colours), and HAS_ONE_BY_ONE_SHAPES, made
    # of the switches of every shape a leaf tests one by one: all but the sphere, which the
    # collapse lays out in packets (clray.accel.wide).
    shapes_h = (KERNELS / "shapes.h").read_text(encoding="utf-8")
    switches = set(re.findall(r"HAS_[A-Z_]+", shapes_h))
    others = {"HAS_PLANES", "HAS_TRIANGLES", "HAS_VERTEX_COLORS", "HAS_ONE_BY_ONE_SHAPES"}
    assert switches - others == {s.switch.upper() for s in SHAPES}
    one_by_one = re.search(r"^#define HAS_ONE_BY_ONE_SHAPES (.*)$", shapes_h, flags=re.MULTILINE)
    assert one_by_one is not None
    assert set(re.findall(r"HAS_[A-Z_]+", one_by_one.group(1))) == {
        s.switch.upper() for s in SHAPES if s.prim != layout.PRIMS["PRIM_SPHERE"]}


def test_the_names_are_one_name() -> None:
    assert [shape.kind for shape in SHAPES] == list(SHAPE_KINDS)
    for shape in SHAPES:
        assert shape.struct.lower() == shape.kind
        assert layout.STRUCTS[shape.struct] is shape.record
        assert getattr(layout, shape.prim_name) == shape.prim
        assert shape.record.itemsize % 16 == 0


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.kind)
def test_scene_keys_are_the_model_fields(shape: Shape) -> None:
    # clray.scene.check writes a model object back as its fields: they must be its keys.
    required, optional = shape.keys
    fields = {f.name for f in dataclasses.fields(shape.model)} - {"material"}
    assert fields == set(required) | set(optional)


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.kind)
def test_the_declared_lengths_are_the_fields_the_parser_takes_as_lengths(shape: Shape) -> None:
    # A field whose 0 the scene's own check refuses as a length ("must be > 0").
    taken = set()
    for name, value in EXAMPLES[shape.kind].items():
        if isinstance(value, int | float):
            try:
                scene_from_dict({"camera": {"position": [0, 0, 9], "look_at": [0, 0, 0]},
                                 "objects": [{"type": shape.kind, **EXAMPLES[shape.kind],
                                              name: 0}]})
            except SceneError as err:
                taken |= {name} if err.message == "must be > 0, got 0" else set()
    fields = {f.name for t in shape.types for f in dataclasses.fields(t)}
    assert set(shape.lengths) <= fields
    assert taken == set(shape.lengths) & set(EXAMPLES[shape.kind])


@pytest.mark.parametrize("shape", [s for s in SHAPES if s.lengths], ids=lambda s: s.kind)
def test_a_transform_shrinks_no_length_below_the_limit(shape: Shape) -> None:
    """As the scene's own values: a torus's tube shrank below 1e-30 unchecked. The example's
    lengths are made small first (a scale below 1e-30 is refused by itself)."""
    spec = {name: value * 1e-29 if name in shape.lengths else value
            for name, value in EXAMPLES[shape.kind].items()}
    smallest = min(spec[name] for name in shape.lengths if name in spec)
    with pytest.raises(SceneError) as info:
        scene_from_dict({"camera": {"position": [0, 0, 9], "look_at": [0, 0, 0]},
                         "objects": [{"type": shape.kind, **spec,
                                      "transform": {"scale": 0.5 * L.MIN_LENGTH / smallest}}]})
    assert str(info.value).startswith("objects[0].transform: shrinks the object below 1e-30")


def test_every_shape_has_an_example() -> None:
    assert set(EXAMPLES) == set(SHAPE_KINDS)


def _example(kind: str) -> object:
    spec = {"type": kind, **EXAMPLES[kind]}
    scene = scene_from_dict({"camera": {"position": [0, 0, 9], "look_at": [0, 0, 0]},
                             "objects": [spec]})
    return scene.objects[0]


def _rays(n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3)) * 4.0
    d = rng.normal(size=(n, 3)) - o / 4.0  # mostly towards the shape
    return o, d


def _hits(shape: Shape, obj: object, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(rays, crossings) t of the shape's crossings, inf where none."""
    return np.stack([t for t, _ in shape.intersect(obj, o, d)], axis=1)


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.kind)
def test_packed_bounds_hold_every_crossing(shape: Shape) -> None:
    obj = _example(shape.kind)
    records, lo, hi = shape.pack([obj], np.zeros((1, 3)))
    assert len(records) == len(lo) == len(hi) == shape.primitives(obj) == 1
    o, d = _rays(4000)
    t = _hits(shape, obj, o, d)
    hit = np.isfinite(t)
    assert hit.sum() > 100, "the rays should cross the shape"
    points = (o[:, None, :] + t[..., None] * d[:, None, :])[hit]
    slack = 1e-6 * (1.0 + np.abs(points))
    assert np.all(points >= lo[0] - slack) and np.all(points <= hi[0] + slack)


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.kind)
def test_placement_moves_the_crossings_with_the_shape(shape: Shape) -> None:
    obj = _example(shape.kind)
    # A quarter turn about y, a uniform scale of 2 and a shift: every shape survives it.
    a = 2.0 * np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    shift = np.array([3.0, -1.0, 0.5])
    assert similarity_scale(a) == 2.0
    moved = shape.place(obj, a, shift)
    assert isinstance(moved, shape.model)
    o, d = _rays(2000)
    # The same rays moved along: the same t (directions are scaled too).
    t0, t1 = _hits(shape, obj, o, d), _hits(shape, moved, o @ a.T + shift, d @ a.T)
    np.testing.assert_allclose(np.sort(t1, axis=1), np.sort(t0, axis=1), rtol=1e-7, atol=1e-9)
    centre, size = shape.centre_size(moved)
    assert centre.shape == (3,) and size > 0


@pytest.mark.parametrize("shape", [s for s in SHAPES if s.kind != "box"],
                         ids=lambda s: s.kind)
def test_uneven_scales_leave_a_round_shape_to_an_instance(shape: Shape) -> None:
    moved = shape.place(_example(shape.kind), np.diag([1.0, 2.0, 1.0]), np.zeros(3))
    assert moved == f"scales or shears unevenly, which a {shape.kind} does not survive"


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.kind)
def test_surface_normals_are_unit_at_crossings(shape: Shape) -> None:
    obj = _example(shape.kind)
    o, d = _rays(2000, seed=2)
    for t, part in shape.intersect(obj, o, d):
        ok = np.isfinite(t)
        n, uv = shape.surface(obj, o[ok] + t[ok, None] * d[ok], part[ok])
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
        assert uv.shape == (ok.sum(), 2) and np.all(np.isfinite(uv))
