"""`transform` on every object: exact placement on the host (float64) where the shape survives
the transform, and a one-object instance (intersected in the shape's own frame) where it does
not; inside a group, where an instance cannot nest, a one-line error naming the key."""

from __future__ import annotations

import numpy as np
import pytest

from clray.cli import main
from clray.errors import SceneError
from clray.scene import model as M
from clray.scene.load import scene_from_dict
from clray.scene.transform import rotation_matrix
from clray.shapes.box import place as place_box

CAMERA = {"position": [0, 0, 10], "look_at": [0, 0, 0]}


def placed(obj: dict, transform: dict) -> M.SceneObject:
    return scene_from_dict({"camera": CAMERA, "objects": [{**obj, "transform": transform}]}
                           ).objects[0]


def error(obj: dict, transform: dict) -> str:
    with pytest.raises(SceneError) as info:
        placed(obj, transform)
    return str(info.value)


SPHERE = {"type": "sphere", "center": [1, 0, 0], "radius": 0.5}


def test_sphere_under_a_similarity() -> None:
    s = placed(SPHERE, {"scale": 2, "rotate": [0, 0, 90], "translate": [0, 0, 3]})
    # Scale first: (2, 0, 0); a quarter turn about z: (0, 2, 0); then up 3 in z.
    np.testing.assert_allclose(s.center, (0, 2, 3), rtol=0, atol=1e-15)
    assert s.radius == 1.0
    mirrored = placed(SPHERE, {"scale": [-3, 3, 3]})
    assert (mirrored.center, mirrored.radius) == ((-3.0, 0.0, 0.0), 1.5)


def test_plane_normal_follows_the_inverse_transpose() -> None:
    plane = {"type": "plane", "point": [0, 0, 0], "normal": [1, 1, 0]}
    p = placed(plane, {"scale": [2, 1, 1]})
    # x + y = 0 stretched along x is x / 2 + y = 0: normal along (1/2, 1, 0).
    np.testing.assert_allclose(p.normal, np.array([0.5, 1, 0]) / np.hypot(0.5, 1), atol=1e-15)
    on_plane = np.array([1.0, -1.0, 0.0]) * [2, 1, 1]
    assert abs(np.dot(on_plane, p.normal)) < 1e-15


def test_box_quarter_turns_stay_boxes() -> None:
    box = {"type": "box", "min": [0, 0, 0], "max": [1, 2, 3]}
    b = placed(box, {"rotate": [0, 90, 0], "translate": [10, 0, 0]})
    # About y, x -> -z and z -> x: the box spans x 10..13, y 0..2, z -1..0.
    np.testing.assert_allclose(b.min, (10, 0, -1), atol=1e-15)
    np.testing.assert_allclose(b.max, (13, 2, 0), atol=1e-15)
    turned = placed(box, {"rotate": [0, 30, 0]})
    assert isinstance(turned, M.Instance) and turned.group.objects[0].max == (1.0, 2.0, 3.0)
    np.testing.assert_allclose(turned.matrix[:, :3], rotation_matrix((0, 30, 0)), atol=0)


def test_box_keeps_axes_whose_scales_differ_by_1e12_or_more() -> None:
    """The noise cleanup compared each entry with the whole matrix's largest, so beside a
    scale of 1e12 a scale of 1 was taken for rounding noise: the box became a line."""
    unit_box = M.Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 0)
    stretched = place_box(unit_box, np.diag([1e13, 1.0, 1.0]), np.zeros(3))
    assert (stretched.min, stretched.max) == ((0.0, 0.0, 0.0), (1e13, 1.0, 1.0))
    # Scale x first, then a quarter turn about z: x -> y and y -> -x.
    turned = place_box(unit_box, rotation_matrix((0, 0, 90)) @ np.diag([1e12, 1.0, 1.0]),
                       np.zeros(3))
    np.testing.assert_allclose(turned.min, (-1, 0, 0), rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(turned.max, (0, 1e12, 1), rtol=1e-15, atol=1e-15)
    b = placed({"type": "box", "min": [0, 0, 0], "max": [1, 1, 1]},
               {"scale": [1e12, 1, 1], "rotate": [0, 0, 90]})
    np.testing.assert_allclose(b.min, (-1, 0, 0), rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(b.max, (0, 1e12, 1), rtol=1e-15, atol=1e-15)


def test_box_turned_off_the_axes_by_a_small_column_is_an_instance() -> None:
    """A column whose entries are all small beside another column's is no column of noise:
    a shear or turn there still takes the box off the axes."""
    a = rotation_matrix((0, 0, 0)) @ np.diag([1e13, 1.0, 1.0])
    a[:2, 1] = rotation_matrix((0, 0, 30))[:2, 1]  # y turned 30 degrees within the xy plane
    reason = place_box(M.Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 0), a, np.zeros(3))
    assert isinstance(reason, str) and "off the axes" in reason


def test_cylinder_and_cone_rotate_and_scale_uniformly() -> None:
    cyl = placed({"type": "cylinder", "base": [0, 0, 0], "axis": [0, 1, 0], "radius": 1,
                  "height": 2}, {"rotate": [90, 0, 0], "scale": 0.5})
    np.testing.assert_allclose(cyl.axis, (0, 0, 1), atol=1e-15)
    assert (cyl.radius, cyl.height) == (0.5, 1.0)
    cone = placed({"type": "cone", "apex": [0, 1, 0], "axis": [0, -1, 0], "angle": 30,
                   "height": 1}, {"translate": [1, 1, 1], "scale": 2})
    assert (cone.apex, cone.axis, cone.angle, cone.height) == ((1.0, 3.0, 1.0), (0.0, -1.0, 0.0),
                                                               30.0, 2.0)
    stretched = placed({"type": "cylinder", "base": [0, 0, 0], "axis": [0, 1, 0], "radius": 1,
                        "height": 2}, {"scale": [1, 2, 1]})
    assert isinstance(stretched, M.Instance)
    np.testing.assert_array_equal(stretched.matrix, [[1, 0, 0, 0], [0, 2, 0, 0], [0, 0, 1, 0]])
    sheared = placed(SPHERE, {"matrix": [[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                         [0, 0, 0, 1]]})
    assert isinstance(sheared, M.Instance) and sheared.group.objects[0].radius == 0.5


def group_error(obj: dict) -> str:
    with pytest.raises(SceneError) as info:
        scene_from_dict({"camera": CAMERA, "groups": {"g": {"objects": [obj]}}})
    return str(info.value)


def test_inside_a_group_what_would_nest_is_an_error() -> None:
    assert group_error({**SPHERE, "transform": {"scale": [1, 2, 1]}}).startswith(
        "groups.g.objects[0].transform: scales or shears unevenly, which a sphere does not "
        "survive, and inside a group")
    assert group_error({"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0]}).startswith(
        "groups.g.objects[0].type: a group holds bounded primitives")
    assert group_error({"type": "instance", "group": "g"}).startswith(
        "groups.g.objects[0].type: a group holds bounded primitives")


def test_triangle_keeps_its_outward_side_when_mirrored() -> None:
    tri = {"type": "triangle", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]]}
    t = placed(tri, {"scale": [1, 1, -1]})
    v0, v1, v2 = np.array(t.vertices)
    # The original faces +z; mirrored in z its outward side faces -z.
    np.testing.assert_allclose(np.cross(v1 - v0, v2 - v0), (0, 0, -1), atol=1e-15)


def test_matrix_equals_the_composed_transform() -> None:
    by_parts = placed(SPHERE, {"scale": 2, "rotate": [0, 0, 90], "translate": [0, 0, 3]})
    by_matrix = placed(SPHERE, {"matrix": [[0, -2, 0, 0], [2, 0, 0, 0], [0, 0, 2, 3],
                                           [0, 0, 0, 1]]})
    np.testing.assert_allclose(by_matrix.center, by_parts.center, atol=1e-15)
    assert by_matrix.radius == by_parts.radius


def test_mesh_normals_stay_perpendicular_under_shear() -> None:
    mesh = {"type": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
            "faces": [[0, 1, 2]], "normals": [[0, 0, 1]] * 3}
    m = placed(mesh, {"matrix": [[1, 0, 0.7, 0], [0, 1, 0, 0], [0.3, 0, 1, 0], [0, 0, 0, 1]]})
    edges = m.vertices[[1, 2]] - m.vertices[0]
    assert np.abs(edges @ m.normals[0]).max() < 1e-15


@pytest.mark.parametrize(("transform", "message"), [
    ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]},
     "objects[0].transform.matrix: expected 4 rows of 4 numbers"),
    ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]},
     "objects[0].transform.matrix[3]: must be [0, 0, 0, 1]"),
    ({"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]},
     "objects[0].transform.matrix: is singular"),
    ({"matrix": [[1, 0, 0, 0]] * 4, "scale": 2}, "objects[0].transform: give matrix or scale"),
    ({"scale": 1e25}, "objects[0].transform: moves the object beyond 1e+30"),
    ({"scale": 1e-29}, "objects[0].transform: shrinks the object below 1e-30"),
    # An ellipsoid (an instance): A and t are within limits, the placed box is not.
    ({"scale": [1e25, 1, 1]}, "objects[0].transform: moves the object beyond 1e+30"),
])
def test_bad_transforms_name_the_key(transform: dict, message: str) -> None:
    sphere = {"type": "sphere", "center": [1e6, 0, 0], "radius": 0.05}
    assert error(sphere, transform).startswith(message)


def test_a_transform_past_float32_is_exit_3_in_one_line(capsys, tmp_path) -> None:
    """The stretched sphere's box (1e40) reached the BVH build, a ValueError traceback."""
    scene = tmp_path / "s.toml"
    scene.write_text('[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n'
                     '[[lights]]\ntype = "point"\nposition = [0, 5, 5]\n'
                     '[[objects]]\ntype = "sphere"\ncenter = [1e20, 0, 0]\nradius = 1\n'
                     'transform = {scale = [1e20, 1, 1]}\n')
    out = tmp_path / "o.png"
    assert main(["render", str(scene), "-W", "16", "-H", "12", "-o", str(out)]) == 3
    lines = capsys.readouterr().err.splitlines()
    assert lines == [f"clray: error: {scene}: objects[0].transform: moves the object beyond "
                     "1e+30 in magnitude (largest 1e+40)"]
    assert not out.exists()


def test_a_cone_whose_rim_passes_the_limit_is_exit_3_in_one_line(capsys, tmp_path) -> None:
    """Height and angle each within their limits, the rim radius (height x tan(angle),
    5.7e37 here) was not checked: the scene rendered with a warning, and at height 1e30 its
    bounds (5.7e38) reached the BVH build, a ValueError traceback."""
    scene = tmp_path / "cone.toml"
    scene.write_text('[render]\nwidth = 32\nheight = 18\nspp = 1\nmax_depth = 0\n'
                     '[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\n'
                     '[materials.m]\ncolor = [1, 1, 1]\n'
                     '[[objects]]\ntype = "cone"\napex = [0, 0, -1]\naxis = [0, 0, -1]\n'
                     'angle = 89.9999999\nheight = 1e29\nmaterial = "m"\n')
    out = tmp_path / "o.png"
    assert main(["render", str(scene), "-o", str(out)]) == 3
    lines = capsys.readouterr().err.splitlines()
    assert lines == [f"clray: error: {scene}: objects[0]: the cone's rim radius (height x "
                     "tan(angle)) is 5.73e+37, beyond 1e+30 in magnitude"]
    assert not out.exists()
