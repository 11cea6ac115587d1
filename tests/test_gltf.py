"""glTF 2.0 files (clray.scene.gltf, clray.scene.parse_gltf): the node hierarchy's placements
and instances against float64 numpy, texture orientation, the material rule, the file's camera,
every warning and refusal, the exit-3 command, and the Khronos sample model rendered."""

from __future__ import annotations

import base64
import json
import math
import struct
import tomllib
from pathlib import Path

import numpy as np
import pytest

from clray.cli import main
from clray.errors import SceneError
from clray.model_scene import model_scene_data
from clray.reference.texture import image_texel
from clray.scene import model as M
from clray.scene.emitters import emissive_triangles
from clray.scene.gltf import GltfMaterial
from clray.scene.load import scene_from_dict
from clray.scene.parse_gltf import gltf_material
from tests.gltf_files import CUBE_FACES, CUBE_VERTICES, Builder, glb_bytes, instanced_cubes

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "scenes" / "models"


def load(path: Path, **spec) -> M.Scene:
    return scene_from_dict({"camera": {"position": [0, 0, 30], "look_at": [0, 0, 0]},
                            "objects": [{"type": "mesh", "file": path.name, **spec}]},
                           path.parent / "scene.toml")


def world_vertices(scene: M.Scene) -> list[np.ndarray]:
    out = []
    for obj in scene.objects:
        if isinstance(obj, M.Mesh):
            out.append(obj.vertices[obj.faces])
        else:
            a, t = obj.matrix[:, :3], obj.matrix[:, 3]
            mesh = obj.group.objects[0]
            out.append(mesh.vertices[mesh.faces] @ a.T + t)
    return out


def rotation_z(degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_a_mesh_of_several_nodes_becomes_instances_of_one_group(tmp_path, suffix):
    path = instanced_cubes().save(tmp_path / f"m{suffix}")
    scene = load(path, transform={"scale": 2, "translate": [1, 0, 0]})
    baked, *instances = scene.objects
    assert isinstance(baked, M.Mesh) and len(baked.faces) == 1
    assert len(instances) == 3 and all(isinstance(i, M.Instance) for i in instances)
    assert len({id(i.group) for i in instances}) == 1  # one copy on the device
    # float64 by hand: the object's transform after the parent's and the child's translation.
    for k in range(3):
        expected = 2 * (CUBE_VERTICES[CUBE_FACES] + [3.0 * k, 10, 0]) + [1, 0, 0]
        got = world_vertices(scene)[1 + k]
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    # The triangle: scale 2, a quarter turn about z, translate z -5 (TRS), then the object's.
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)
    expected = 2 * ((2 * tri) @ rotation_z(90).T + [0, 0, -5]) + [1, 0, 0]
    np.testing.assert_allclose(baked.vertices[baked.faces[0]], expected, atol=1e-6)


def test_inside_a_group_the_placements_are_copies(tmp_path):
    instanced_cubes().save(tmp_path / "m.glb")
    scene = scene_from_dict({"camera": {"position": [0, 0, 30], "look_at": [0, 0, 0]},
                             "groups": {"g": {"objects": [{"type": "mesh", "file": "m.glb"}]}},
                             "objects": [{"type": "instance", "group": "g"}]},
                            tmp_path / "s.toml")
    (inst,) = scene.objects
    (mesh,) = inst.group.objects
    assert len(mesh.faces) == 3 * 12 + 1
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    np.testing.assert_allclose(lo, [-2, 0, -5], atol=1e-6)
    np.testing.assert_allclose(hi, [7, 11, 1], atol=1e-6)


def test_an_instance_past_the_limits_is_refused_by_the_copys_check(tmp_path):
    """A node's matrix within limits still carries a mesh far out past them: the mesh is
    placed as a copy, whose check names the transform (an instance reached the BVH build)."""
    b = Builder()
    cube = b.mesh(CUBE_VERTICES * 1e20, CUBE_FACES)
    b.node(mesh=cube)
    b.node(mesh=cube, translation=[1e20, 0, 0])
    path = b.save(tmp_path / "m.glb")
    with pytest.raises(SceneError) as caught:
        load(path, transform={"scale": 1e20})
    assert str(caught.value).endswith("objects[0].transform: moves vertices beyond 1e+30 in "
                                      "magnitude (largest 1e+40)")


def test_a_matrix_node_with_a_mirror_keeps_faces_outward(tmp_path):
    b = Builder()
    cube = b.mesh(CUBE_VERTICES - 0.5, CUBE_FACES)
    m = np.array([[-1.0, 0.3, 0, 4], [0, 2, 0, 5], [0, 0, 1, 6], [0, 0, 0, 1]])
    b.node(mesh=cube, matrix=m.T.reshape(-1).tolist())  # glTF's matrices are column-major
    (mesh,) = load(b.save(tmp_path / "m.glb")).objects
    np.testing.assert_allclose(mesh.vertices, (CUBE_VERTICES - 0.5) @ m[:3, :3].T + m[:3, 3],
                               atol=1e-12)
    corners = mesh.vertices[mesh.faces]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    outward = corners.mean(axis=1) - [4, 5, 6]
    assert np.all(np.sum(normal * outward, axis=1) > 0)


def test_texture_v_runs_down_the_image(tmp_path):
    """glTF's (0, 0) is the image's top-left corner; clray's v runs up the image."""
    texels = np.zeros((2, 2, 3), dtype=np.uint8)
    texels[0, 0] = (255, 0, 0)  # the top-left texel red
    texels[1, 1] = (0, 0, 255)  # the bottom-right blue
    b = Builder()
    texture = b.image(texels)
    mat = b.material(pbrMetallicRoughness={"baseColorTexture": {"index": texture},
                                           "baseColorFactor": [1, 1, 0.5, 1]})
    quad = b.mesh([[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 1, 2]], mat,
                  uvs=[[0.25, 0.25], [0.75, 0.75], [0.75, 0.25]])
    b.node(mesh=quad)
    scene = load(b.save(tmp_path / "t.gltf"))
    (mesh,) = scene.objects
    texture = scene.materials[mesh.material].texture
    got = image_texel(texture.image, mesh.uvs[:, 0], mesh.uvs[:, 1], texture.repeat)
    # Texel centres, times baseColorFactor (glTF multiplies; clray's texture holds the product).
    np.testing.assert_allclose(got, [[1, 0, 0], [0, 0, 0.5], [0, 0, 0]], atol=1e-6)


def test_joined_meshes_keep_the_uvs_of_those_that_have_them(tmp_path):
    """A textured mesh placed beside one without TEXCOORD_0 keeps its uvs (the other's are
    zero), as the primitives of one mesh do: dropping them all smeared the texture."""
    b = Builder()
    mat = b.material(pbrMetallicRoughness={"baseColorTexture": {"index": b.image(
        np.zeros((2, 2, 3), dtype=np.uint8))}})
    tri = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    b.node(mesh=b.mesh(tri, [[0, 1, 2]], mat, uvs=[[0.0, 0.0], [1.0, 0.0], [0.0, 0.75]]))
    b.node(mesh=b.mesh(tri, [[0, 1, 2]]), translation=[3, 0, 0])
    (mesh,) = load(b.save(tmp_path / "mix.gltf")).objects
    assert mesh.uvs is not None
    np.testing.assert_array_equal(mesh.uvs, [[0, 1], [1, 1], [0, 0.25], [0, 0], [0, 0], [0, 0]])


SMOOTH = [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8]]


@pytest.mark.parametrize("join", ["nodes", "primitives"])
def test_a_part_without_normals_shades_flat_beside_a_smooth_one(tmp_path, join):
    """A mesh without NORMAL joined to one with them (two nodes' meshes, or two primitives
    of one mesh) gets its face normals (flat, as glTF asks); the other keeps its own. All
    were dropped, so the smooth part shaded flat too."""
    b = Builder()
    tri = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    smooth = b.mesh(tri, [[0, 1, 2]], normals=SMOOTH)
    flat = b.mesh([[0, 0, 0], [0, 0, 1], [0, 1, 0], [0, 1, 1]], [[0, 1, 2], [2, 1, 3]],
                  colors=[[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]])
    b.node(mesh=smooth)
    if join == "nodes":
        b.node(mesh=flat, translation=[3, 0, 0])
    else:
        b.doc["meshes"][smooth]["primitives"] += b.doc["meshes"].pop(flat)["primitives"]
    (mesh,) = load(b.save(tmp_path / "n.gltf")).objects
    assert mesh.normals is not None
    np.testing.assert_allclose(mesh.normals[:3], SMOOTH, atol=1e-7)
    # The flat part: a vertex a corner, each with its face's normal (-x by the winding).
    np.testing.assert_array_equal(mesh.faces[1:], [[3, 4, 5], [6, 7, 8]])
    np.testing.assert_array_equal(mesh.normals[3:], [[-1, 0, 0]] * 6)
    corners = [[0, 0, 1], [0, 1, 0], [0, 1, 1]]
    np.testing.assert_array_equal(mesh.vertices[3:] - mesh.vertices[3], [
        [0, 0, 0], *corners[:2], corners[1], [0, 0, 1], corners[2]])
    np.testing.assert_array_equal(mesh.colors[3:], [[1, 0, 0], [0, 1, 0], [0, 0, 1],
                                                    [0, 0, 1], [0, 1, 0], [1, 1, 0]])


def test_material_rule():
    def rule(metallic, roughness, **kw):
        base = dict(name="m", color=(0.5, 0.6, 0.7), alpha=1.0, emission=(0, 0, 0),
                    texture=None)
        return gltf_material(GltfMaterial(metallic=metallic, roughness=roughness,
                                          **{**base, **kw}), None)

    rough = rule(0.0, 1.0)
    assert (rough.diffuse, rough.reflect, rough.specular, rough.color) == (
        1.0, 0.0, 0.0, (0.5, 0.6, 0.7))
    mirror = rule(1.0, 0.0)
    assert (mirror.diffuse, mirror.reflect, mirror.specular) == (0.0, 1.0, 1.0)
    half = rule(0.5, 0.5)
    assert half.reflect == pytest.approx(0.25) and half.diffuse == pytest.approx(0.75)
    # Blinn-Phong's 2 / alpha^2 - 2 for alpha = 0.25, over 4 for Phong's wider lobe.
    assert half.shininess == pytest.approx((2 / 0.25**2 - 2) / 4)
    assert rule(0.0, 0.5, alpha=0.25).transmit == 0.75
    assert rule(0.0, 1.0, emission=(1, 0.5, 0)).emission == (1, 0.5, 0)


def test_emissive_faces_light_the_scene_and_are_not_instanced(tmp_path):
    b = Builder()
    glow = b.material(emissiveFactor=[1, 0.5, 0.25])
    cube = b.mesh(CUBE_VERTICES, CUBE_FACES, glow)
    b.node(mesh=cube)
    b.node(mesh=cube, translation=[2, 0, 0])
    scene = load(b.save(tmp_path / "e.glb"))
    assert all(isinstance(o, M.Mesh) for o in scene.objects)
    lights = emissive_triangles(scene)
    assert len(lights) == 24 and lights[0].color == (1.0, 0.5, 0.25)


def test_the_scene_material_replaces_the_files(tmp_path):
    instanced_cubes().save(tmp_path / "m.glb")
    scene = scene_from_dict({"camera": {"position": [0, 0, 30], "look_at": [0, 0, 0]},
                             "materials": {"blue": {"color": [0, 0, 1]}},
                             "objects": [{"type": "mesh", "file": "m.glb",
                                          "material": "blue"}]}, tmp_path / "s.toml")
    meshes = [o if isinstance(o, M.Mesh) else o.group.objects[0] for o in scene.objects]
    assert all(m.face_materials is None and m.material == 0 for m in meshes)


def test_the_files_first_camera_frames_the_automatic_scene(tmp_path, monkeypatch):
    b = instanced_cubes()
    b.doc["cameras"] = [{"type": "perspective",
                         "perspective": {"yfov": 0.5, "aspectRatio": 2.0, "znear": 0.1}},
                        {"type": "orthographic", "orthographic": {"xmag": 1, "ymag": 1}}]
    b.node(camera=0, translation=[1, 2, 3], rotation=[0, 0.7071067811865476, 0,
                                                      0.7071067811865476])
    b.node(camera=1)
    b.save(tmp_path / "c.glb")
    monkeypatch.chdir(tmp_path)
    data = model_scene_data(Path("c.glb"))
    camera = data["camera"]
    assert data["render"]["width"] == 2 * data["render"]["height"]
    assert camera["vfov"] == pytest.approx(math.degrees(0.5), rel=1e-5)
    np.testing.assert_allclose(camera["position"], [1, 2, 3])
    # A quarter turn about y turns the camera's -z view to -x.
    np.testing.assert_allclose(camera["look_at"], [0, 2, 3], atol=1e-6)
    np.testing.assert_allclose(camera["up"], [0, 1, 0], atol=1e-6)
    turned = model_scene_data(Path("c.glb"), up="z")["camera"]  # --up z turns it too
    np.testing.assert_allclose(turned["position"], [1, 3, -2], atol=1e-6)


def test_view_with_a_file_that_has_a_camera_is_a_usage_error(tmp_path, monkeypatch, capsys):
    # The file's camera sets the view: --view top was ignored, though `clray scene`'s header
    # said --view top. Refused as --view is with a scene file; the header leaves it out.
    b = instanced_cubes()
    b.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.1}}]
    b.node(camera=0, translation=[1, 2, 30])
    b.save(tmp_path / "c.glb")
    monkeypatch.chdir(tmp_path)
    for command in (["render", "c.glb", "--view", "top", "-o", "c.png"],
                    ["scene", "c.glb", "--view", "top"]):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert "--view: c.glb has a camera of its own (nodes[" in err and len(
            err.splitlines()) == 1
    assert not (tmp_path / "c.png").exists()
    assert main(["scene", "c.glb"]) == 0
    assert capsys.readouterr().out.startswith("# The automatic scene of c.glb (clray scene).")


def test_orthographic_camera(tmp_path, monkeypatch):
    b = instanced_cubes()
    b.doc["cameras"] = [{"type": "orthographic", "orthographic": {"xmag": 3, "ymag": 1.5}}]
    b.node(camera=0, translation=[0, 0, 20])
    b.save(tmp_path / "o.gltf")
    monkeypatch.chdir(tmp_path)
    data = model_scene_data(Path("o.gltf"))
    assert data["camera"]["type"] == "orthographic" and data["camera"]["height"] == 3.0
    assert data["render"]["width"] == 2 * data["render"]["height"]


def test_the_widest_yfov_the_reader_takes_stays_under_180_degrees(tmp_path, monkeypatch):
    # pi - 1e-6, the reader's bound, is 179.99994 degrees: written to 6 digits it was 180.0,
    # which the scene refused as camera.vfov, naming neither the file nor the glTF key.
    b = instanced_cubes()
    b.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": math.pi - 1e-6}}]
    b.node(camera=0, translation=[0, 0, 20])
    b.save(tmp_path / "wide.gltf")
    monkeypatch.chdir(tmp_path)
    from clray.model_scene import load_model_scene

    vfov = load_model_scene(Path("wide.gltf")).camera.vfov
    assert vfov == math.degrees(math.pi - 1e-6) and vfov < 180


@pytest.mark.parametrize(("camera", "parent", "key", "message"), [
    ({"type": "perspective", "perspective": {"yfov": 1.0}}, {"translation": [1e30, 0, 0]},
     "camera.position", r"must be at most 1e\+30 in magnitude, got \[2e\+30"),
    ({"type": "orthographic", "orthographic": {"ymag": 1e30}}, {"scale": [2, 2, 2]},
     "camera.height", r"must be at most 1e\+30 in magnitude, got 4e\+30")])
def test_a_file_camera_the_scene_cannot_take_names_the_file_and_node(
        tmp_path, monkeypatch, camera, parent, key, message):
    # Each number within the limit, the nodes placing the camera beyond it: the error named
    # only the automatic scene's [camera] key.
    b = instanced_cubes()
    b.doc["cameras"] = [camera]
    child = b.node(root=False, camera=0, translation=[1e30, 0, 0] if key == "camera.position"
                   else [0, 0, 20])
    b.node(children=[child], **parent)
    b.save(tmp_path / "far.gltf")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SceneError, match=rf"^far\.gltf: nodes\[{child}\]\.camera: as the "
                       rf"automatic scene's {key}: {message}"):
        model_scene_data(Path("far.gltf"))


def warnings_of(tmp_path, doc_edit, name="w.glb") -> tuple[str, ...]:
    b = instanced_cubes()
    doc_edit(b)
    return load(b.save(tmp_path / name)).warnings


@pytest.mark.parametrize("edit, needle", [
    (lambda b: b.doc["meshes"][1]["primitives"][0].update(mode=0), "mode POINTS"),
    (lambda b: b.doc["meshes"][1]["primitives"][0].update(mode=1), "mode LINES"),
    (lambda b: b.doc["nodes"][0].update(skin=0), "skins"),
    (lambda b: b.doc["meshes"][0]["primitives"][0].update(targets=[{}]), "morph targets"),
    (lambda b: b.doc.update(animations=[{"channels": []}]), "animations"),
    (lambda b: b.doc.update(extensionsUsed=["KHR_materials_clearcoat"]),
     "KHR_materials_clearcoat"),
    (lambda b: b.doc["materials"][0].update(normalTexture={"index": 0}), "normalTexture"),
    (lambda b: b.doc["materials"][0].update(emissiveTexture={"index": 0}), "emissiveTexture"),
    (lambda b: b.doc["materials"][0].update(alphaMode="MASK"), "alphaMode MASK"),
])
def test_unsupported_things_are_one_warning_each(tmp_path, edit, needle):
    warned = [w for w in warnings_of(tmp_path, edit) if needle in w]
    assert len(warned) == 1, warned
    assert "w.glb" in warned[0]


def test_strips_and_fans_are_triangles(tmp_path):
    b = Builder()
    quad = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]
    b.node(mesh=b.mesh(quad, [0, 1, 2, 3], mode=5))
    b.node(mesh=b.mesh(quad, [0, 1, 3, 2], mode=6), translation=[0, 0, 1])
    (mesh,) = load(b.save(tmp_path / "s.glb")).objects
    strip, fan = mesh.faces.reshape(2, 2, 3)
    np.testing.assert_array_equal(strip, [[0, 1, 2], [2, 1, 3]])
    np.testing.assert_array_equal(fan, [[4, 5, 7], [4, 7, 6]])


def test_a_primitive_without_a_whole_triangle_draws_nothing(tmp_path):
    # Two indices (found by the fuzzer): no triangle, so the mesh is left out as a mesh of
    # points is, not a mesh of no faces; alone in the file it is "no triangles to render".
    b = Builder()
    b.node(mesh=b.mesh(CUBE_VERTICES, CUBE_FACES))
    b.node(mesh=b.mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [0, 1]))
    loaded = load(b.save(tmp_path / "two.glb"))
    (mesh,) = loaded.objects
    np.testing.assert_array_equal(mesh.faces, CUBE_FACES)
    assert [w for w in loaded.warnings if "fewer than three indices" in w] == [
        "objects[0].file: two.glb: primitives of fewer than three indices are not drawn (no "
        "whole triangle)"]
    alone = Builder()
    alone.node(mesh=alone.mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [0, 1]))
    with pytest.raises(SceneError, match="no triangles to render"):
        load(alone.save(tmp_path / "alone.glb"))


def test_sparse_accessor_replaces_values(tmp_path):
    b = Builder()
    cube = b.mesh(CUBE_VERTICES, CUBE_FACES)
    b.node(mesh=cube)
    where = b.view(np.array([7], np.uint16).tobytes())
    value = b.view(np.array([[5, 5, 5]], np.float32).tobytes())
    b.doc["accessors"][0]["sparse"] = {"count": 1, "indices": {"bufferView": where,
                                                                "componentType": 5123},
                                       "values": {"bufferView": value}}
    (mesh,) = load(b.save(tmp_path / "s.glb")).objects
    np.testing.assert_array_equal(mesh.vertices[7], [5, 5, 5])
    np.testing.assert_array_equal(mesh.vertices[:7], CUBE_VERTICES[:7])


def _zeros_file(tmp_path: Path, counts: list[int], **attributes: int) -> Path:
    """A .gltf of one mesh a count, each a POSITION accessor of zeros (no buffer view: no
    bytes in the file however many it declares), with more attributes of given counts."""
    accessors = [{"componentType": 5126, "count": n, "type": "VEC3"} for n in counts]
    extra = {}
    for name, n in attributes.items():
        extra[name] = len(accessors)
        accessors.append({"componentType": 5126, "count": n,
                          "type": "VEC2" if name == "TEXCOORD_0" else "VEC3"})
    doc = {"asset": {"version": "2.0"}, "accessors": accessors,
           "meshes": [{"primitives": [{"attributes": {"POSITION": i, **extra}}]}
                      for i in range(len(counts))],
           "nodes": [{"mesh": i} for i in range(len(counts))],
           "scenes": [{"nodes": list(range(len(counts)))}]}
    path = tmp_path / "z.gltf"
    path.write_text(json.dumps(doc))
    return path


def test_the_declared_triangles_are_counted_before_any_array_is_built(tmp_path, monkeypatch):
    # Two meshes each under the limit, together over it: each accessor's 50 M zeros were
    # built (7.6 GB) before the triangles were counted. Limits made small, and any array
    # built an error.
    import clray.scene.gltf as gltf
    from clray.scene import limits

    monkeypatch.setattr(limits, "MAX_TRIANGLES", 4)
    monkeypatch.setattr(limits, "MAX_MESH_VERTICES", 12)

    def built(*args, **kwargs):
        raise AssertionError("an accessor was read")

    monkeypatch.setattr(gltf._Reader, "accessor", built)
    with pytest.raises(SceneError, match=r"z\.gltf: meshes\[1\]\.primitives\[0\]: the "
                       r"file's meshes declare 15 vertices and 5 triangles up to here, over "
                       r"the limit of 12 vertices and 4 triangles"):
        load(_zeros_file(tmp_path, [6, 9]))
    with pytest.raises(SceneError, match=r"declare 13 vertices and 4 triangles"):
        load(_zeros_file(tmp_path, [6, 7]))
    # An attribute of more elements than the positions: refused before it is made.
    with pytest.raises(SceneError, match=r"meshes\[0\]\.primitives\[0\]\.attributes\."
                       r"TEXCOORD_0: 1000000 elements for 3 positions"):
        load(_zeros_file(tmp_path, [3], TEXCOORD_0=10**6))


def test_copies_are_counted_against_the_triangle_limit_before_they_are_made(tmp_path,
                                                                            monkeypatch):
    # A glowing mesh is copied for each node that places it: every copy was made before
    # their triangles were counted (a large mesh placed by many nodes filled memory).
    import clray.scene.parse_gltf as parse_gltf
    from clray.scene import limits

    b = Builder()
    glow = b.material(emissiveFactor=[1, 1, 1])
    cube = b.mesh(CUBE_VERTICES, CUBE_FACES, glow)
    for i in range(3):
        b.node(mesh=cube, translation=[3.0 * i, 0, 0])
    monkeypatch.setattr(limits, "MAX_TRIANGLES", 30)  # two copies of the cube's 12 fit
    made = []
    real = parse_gltf.transformed
    monkeypatch.setattr(parse_gltf, "transformed", lambda *a: made.append(1) or real(*a))
    with pytest.raises(SceneError, match="36 triangles is over what is left"):
        load(b.save(tmp_path / "glow.glb"))
    assert len(made) == 2


def _buffers_file(tmp_path: Path, uris: list[str]) -> tuple[Path, bytes]:
    """instanced_cubes() as a .gltf whose buffer views take turns among `buffers` entries of
    these file names (each file a copy of the one buffer); and the buffer's bytes."""
    b = instanced_cubes()
    doc = b.document(None)
    doc["buffers"] = [{"byteLength": len(b.blob), "uri": uri} for uri in uris]
    for i, view in enumerate(doc["bufferViews"]):
        view["buffer"] = i % len(uris)
    for uri in set(uris):
        (tmp_path / uri).write_bytes(bytes(b.blob))
    (tmp_path / "b.gltf").write_text(json.dumps(doc))
    return tmp_path / "b.gltf", bytes(b.blob)


def test_a_buffer_file_named_by_many_buffers_is_read_once(tmp_path, monkeypatch):
    # 25 `buffers` naming one 40 MB .bin were read 25 times (1.07 GB).
    import clray.scene.assets as assets
    import clray.scene.files as files

    path, blob = _buffers_file(tmp_path, ["m.bin"] * 5)
    reads = []
    for module in (assets, files):  # assets' own name for it, and read_regular's

        def counted(stream, n, real=module.read_at_most):
            data = real(stream, n)
            reads.append(data == blob)
            return data

        monkeypatch.setattr(module, "read_at_most", counted)
    scene = load(path)
    assert reads.count(True) == 1
    assert len(scene.objects) == 4  # the triangle and three instances, as from one buffer


def test_a_gltf_files_buffer_files_share_one_limit(tmp_path, monkeypatch):
    # Each within the limit of one file, together over it, as a .glb of them all would be.
    from clray.scene import limits

    path, blob = _buffers_file(tmp_path, ["a.bin", "b.bin"])
    monkeypatch.setattr(limits, "MAX_BINARY_MESH_BYTES", len(blob) * 3 // 2)
    with pytest.raises(SceneError, match=r"b\.gltf: buffers\[1\]\.uri: cannot read b\.bin: "
                       rf"{len(blob)} bytes is over what is left \({len(blob) // 2}\) of "
                       "the limit"):
        load(path)


def broken_cases(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """name -> (file, what the one-line message must say)."""
    good = instanced_cubes()
    glb = good.glb()
    cases = {}

    def doc(name: str, edit, needle: str, suffix=".glb") -> None:
        b = instanced_cubes()
        edit(b.doc)
        cases[name] = (b.save(tmp_path / f"{name}{suffix}"), needle)

    (tmp_path / "truncated.glb").write_bytes(glb[: len(glb) - 7])
    cases["truncated"] = (tmp_path / "truncated.glb", "truncated .glb")
    (tmp_path / "json.gltf").write_bytes(b'{"asset": {"version": "2.0"}, "nodes": [')
    cases["json"] = (tmp_path / "json.gltf", "not glTF JSON")
    doc("accessor", lambda d: d["meshes"][0]["primitives"][0].update(indices=99),
        "meshes[0].primitives[0].indices: 99 is not an index into accessors")
    doc("count", lambda d: d["accessors"][0].update(count=10**6),
        "accessors[0]: 1000000 elements")
    doc("index", lambda d: d["meshes"][0]["primitives"][0].update(material=5),
        "material: 5 is not an index into materials")
    doc("cycle", lambda d: d["nodes"][0].update(children=[3]), "reached twice")
    doc("draco", lambda d: d.update(extensionsRequired=["KHR_draco_mesh_compression"]),
        "KHR_draco_mesh_compression")
    doc("version", lambda d: d["asset"].update(version="1.0"), "asset.version")
    # JSON values of the wrong kind where a number is looked up or compared (found by the fuzzer):
    doc("component", lambda d: d["accessors"][0].update(componentType=[5126]),
        "accessors[0].componentType: expected one of 5120")
    # An integer, as the glTF schema says: 5126.0 is refused (it hashes as 5126 does).
    doc("component_float", lambda d: d["accessors"][0].update(componentType=5126.0),
        "accessors[0].componentType: expected one of 5120")
    doc("huge", lambda d: d["nodes"][0].update(translation=[10**400, 0, 0]),
        "nodes[0].translation: expected 3 numbers")
    # A sparse accessor's indices and values without a buffer view: a KeyError traceback.
    for part in ("indices", "values"):
        doc(f"sparse_{part}", lambda d, part=part: d["accessors"][0].update(sparse={
            "count": 1, "indices": {"bufferView": 0, "componentType": 5125},
            "values": {"bufferView": 0}, part: {"componentType": 5125}}),
            f"accessors[0].sparse.{part}.bufferView: missing required key")
    missing = instanced_cubes().save(tmp_path / "missing.gltf")
    missing.with_suffix(".bin").unlink()
    cases["missing_bin"] = (missing, "buffers[0].uri: cannot read missing.bin: file not found")
    bad = glb_bytes({"asset": {"version": "2.0"}}, b"")
    (tmp_path / "nothing.glb").write_bytes(bad)
    cases["nothing"] = (tmp_path / "nothing.glb", "no triangles to render")
    return cases


CASES = ("truncated", "json", "accessor", "count", "index", "cycle", "draco", "version",
         "component", "component_float", "huge", "sparse_indices", "sparse_values",
         "missing_bin", "nothing")


@pytest.mark.parametrize("name", CASES)
def test_broken_files_are_scene_errors(tmp_path, name):
    path, needle = broken_cases(tmp_path)[name]
    with pytest.raises(SceneError) as caught:
        load(path)
    assert needle in str(caught.value)
    assert path.name in str(caught.value)


@pytest.mark.parametrize("name", ["truncated", "accessor", "missing_bin", "sparse_values"])
def test_broken_file_exits_3_with_one_line(capsys, tmp_path, name):
    path, needle = broken_cases(tmp_path)[name]
    out = tmp_path / "out.png"
    assert main(["render", str(path), "-o", str(out), "-W", "8", "-H", "6"]) == 3
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if not line.startswith("clray: warning:")]
    assert len(lines) == 1 and lines[0].startswith("clray: error: "), err
    assert needle in lines[0] and path.name in lines[0]
    assert not out.exists()


def test_glb_header_lengths_are_checked(tmp_path):
    glb = bytearray(instanced_cubes().glb())
    struct.pack_into("<I", glb, 12, 10**6)  # the JSON chunk runs past the end
    (tmp_path / "c.glb").write_bytes(bytes(glb))
    with pytest.raises(SceneError, match="runs past the end"):
        load(tmp_path / "c.glb")


def test_sample_model_loads_as_the_gltf_and_glb_alike():
    glb, gltf = load(MODELS / "BoxTextured.glb"), load(MODELS / "BoxTextured" /
                                                       "BoxTextured.gltf")
    (a,), (b,) = glb.objects, gltf.objects
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.uvs, b.uvs)
    # The node's matrix turns the cube a quarter about x: still the cube [-0.5, 0.5]^3.
    np.testing.assert_allclose(a.vertices.min(axis=0), [-0.5] * 3)
    texture = glb.materials[a.material].texture
    assert texture is not None and texture.image.shape[2] == 3


@pytest.mark.parametrize("name", ["BoxTextured.glb", "BoxTextured/BoxTextured.gltf"])
def test_sample_model_renders_with_its_texture(cl_device, tmp_path, name):
    from PIL import Image

    out = tmp_path / "box.png"
    assert main(["render", str(MODELS / name), "-o", str(out), "-W", "64", "-H", "48",
                 "-q"]) == 0
    image = np.asarray(Image.open(out).convert("RGB")).astype(int)
    # The Cesium logo's green and blue are seen, not only the white and grey of the box.
    green = (image[..., 1] > image[..., 0] + 30) & (image[..., 1] > image[..., 2])
    blue = (image[..., 2] > image[..., 0] + 40)
    assert green.sum() > 20 and blue.sum() > 20


def test_scene_command_writes_a_toml_of_the_model(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(MODELS)
    assert main(["scene", "BoxTextured.glb"]) == 0
    (tmp_path / "box.toml").write_text(capsys.readouterr().out)
    monkeypatch.chdir(tmp_path)
    written = tomllib.loads((tmp_path / "box.toml").read_text())
    assert written["objects"] == [{"type": "mesh", "file": "BoxTextured.glb"}]
    assert written["camera"] == model_scene_data(MODELS / "BoxTextured.glb")["camera"]


# -- vertex colours (PLY red/green/blue, glTF COLOR_0) --------------------------------------


def colored_scene(mesh: M.Mesh) -> M.Scene:
    """The mesh seen head-on under ambient light alone: each pixel is its colour."""
    return M.Scene(None, M.RenderOptions(width=48, height=36, ambient=(1, 1, 1)),
                   M.Camera((0.5, 0.5, 3.0), (0.5, 0.5, 0.0), vfov=30.0),
                   (M.Material("m", color=(1.0, 0.5, 1.0), ambient=1.0, diffuse=0.0),),
                   (), (mesh,))


def test_vertex_colours_blend_across_each_face_as_the_reference(cl_device):
    from tests.reference_check import Tolerance, assert_kernel_matches_reference

    vertices = np.array([[-1.0, -1, 0], [2, -1, 0], [0.5, 2, 0]])
    colors = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]])
    mesh = M.Mesh(vertices, np.array([[0, 1, 2]]), 0, colors=colors)
    scene = colored_scene(mesh)
    # Measured on PoCL and Intel's CPU runtime alike: largest error 1.44e-7, RMSE 2.13e-8.
    assert_kernel_matches_reference(scene, Tolerance(rmse=8.5e-8, err=5.8e-7, off=0))
    from clray.render import render

    image = render(scene).image.astype(np.float64)
    # The centre pixel looks at (0.5, 0.5, 0): barycentrics by hand, in float64, times the
    # material's colour (1, 0.5, 1).
    b = np.linalg.solve(np.vstack([vertices[:, :2].T, np.ones(3)]), [0.5, 0.5, 1.0])
    np.testing.assert_allclose(image[18, 24], (b @ colors) * [1, 0.5, 1], atol=0.02)


def test_instanced_vertex_colours_match_the_reference(cl_device, tmp_path):
    from tests.reference_check import Tolerance, assert_kernel_matches_reference

    b = Builder()
    cube = b.mesh(CUBE_VERTICES - 0.5, CUBE_FACES, colors=CUBE_VERTICES)
    b.node(mesh=cube, translation=[-0.8, 0, 0])
    b.node(mesh=cube, translation=[0.8, 0, 0], rotation=[0, 0.38268343, 0, 0.92387953])
    loaded = load(b.save(tmp_path / "c.glb"))
    assert all(isinstance(o, M.Instance) for o in loaded.objects)
    np.testing.assert_array_equal(loaded.objects[0].group.objects[0].colors, CUBE_VERTICES)
    scene = M.Scene(None, M.RenderOptions(width=48, height=36, ambient=(0.3, 0.3, 0.3)),
                    M.Camera((1.0, 1.5, 4.0), (0.0, 0.0, 0.0), vfov=40.0),
                    (M.Material("m", ambient=1.0, diffuse=0.8),),
                    (M.DirectionalLight((-0.3, -0.8, -0.5)),), loaded.objects)
    # The direction is not unit (length 0.99): render() and the reference both normalise it.
    # Measured on PoCL and Intel's CPU runtime: largest error 6.9e-7, RMSE 6.7e-8 (6.5e-3 and
    # 1.6e-3 while the reference took the direction as given).
    assert_kernel_matches_reference(scene, Tolerance(rmse=2.7e-7, err=2.8e-6, off=0))


def test_ply_colours_are_srgb_decoded_and_rendered(cl_device, tmp_path, monkeypatch):
    from clray.scene.colour import srgb_decode

    header = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
              "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n")
    body = "-1 -1 0 255 0 0\n2 -1 0 0 128 0\n0.5 2 0 0 0 64\n3 0 1 2\n"
    (tmp_path / "c.ply").write_text(header + body)
    scene = load(tmp_path / "c.ply")
    (mesh,) = scene.objects
    np.testing.assert_allclose(mesh.colors, srgb_decode(np.array(
        [[255, 0, 0], [0, 128, 0], [0, 0, 64]]) / 255.0))
    assert not any("colour" in w for w in scene.warnings)
    monkeypatch.chdir(tmp_path)  # the automatic scene's material is white: colours as given
    assert model_scene_data(Path("c.ply"))["materials"]["model"]["color"] == [1.0, 1.0, 1.0]


def test_a_python_scene_keeps_its_vertex_colours_and_checks_them():
    from clray.scene.check import check_scene

    colors = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]])
    mesh = M.Mesh(np.array([[-1.0, -1, 0], [2, -1, 0], [0.5, 2, 0]]), np.array([[0, 1, 2]]), 0,
                  colors=colors)
    checked = check_scene(colored_scene(mesh))
    np.testing.assert_array_equal(checked.objects[0].colors, colors)
    bad = M.Mesh(mesh.vertices, mesh.faces, 0, colors=colors * 2)
    with pytest.raises(SceneError, match=r"objects\[0\].colors: must be linear values in"):
        check_scene(colored_scene(bad))


def test_bytes_after_the_glb_length_are_ignored_with_a_warning(tmp_path):
    # They were reported as "truncated .glb": the file is longer than its header says.
    glb = instanced_cubes().glb()
    (tmp_path / "c.glb").write_bytes(glb)
    (tmp_path / "padded.glb").write_bytes(glb + b"\0" * 5)
    loaded = load(tmp_path / "padded.glb")
    assert [w for w in loaded.warnings if "padded.glb" in w and w.endswith(
        f"ignored: 5 bytes past the length the .glb header gives ({len(glb)})")], loaded.warnings
    np.testing.assert_array_equal(loaded.objects[0].vertices,
                                  load(tmp_path / "c.glb").objects[0].vertices)


def test_zeros_without_a_buffer_view_are_at_most_the_file(tmp_path, monkeypatch):
    # A 689-byte file of 100 M zeros (POSITION, no buffer view) took 4.8 GB and 24 s before
    # it failed. Zeros are charged as if written out; np.zeros of more is never called.
    # (A buffer that cannot be read, declaring any byteLength, adds nothing: below.)
    import clray.scene.gltf as gltf

    made = []
    real = np.zeros
    monkeypatch.setattr(gltf.np, "zeros", lambda shape, *a, **k: made.append(shape)
                        or real(shape, *a, **k))
    path = _zeros_file(tmp_path, [3 * 10**6])
    size = path.stat().st_size
    with pytest.raises(SceneError) as info:
        load(path)
    assert str(info.value) == (
        f"{path.name}: accessors[0]: 36000000 bytes of elements without a buffer view, over the "
        f"{size} bytes of the file and its buffers (an accessor's zeros may be at most as "
        "large as the file)")
    assert made == []
    # A sparse accessor of zeros as large as the positions the file holds is read.
    b = Builder()
    b.node(mesh=b.mesh(CUBE_VERTICES, CUBE_FACES))
    where = b.view(np.array([7], np.uint16).tobytes())
    value = b.view(np.array([[5, 5, 5]], np.float32).tobytes())
    b.doc["accessors"].append({"componentType": 5126, "count": 8, "type": "VEC3", "sparse": {
        "count": 1, "indices": {"bufferView": where, "componentType": 5123},
        "values": {"bufferView": value}}})
    b.doc["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = len(b.doc["accessors"]) - 1
    load(b.save(tmp_path / "s.glb"))


def test_zeros_without_a_buffer_view_read_no_unused_buffer(tmp_path):
    # The cap on an accessor's zeros read every buffer for its size: an unused buffer whose
    # file is missing failed a file that loaded without the zeros. A buffer that cannot be
    # read now counts nothing (its declared byteLength could be anything).
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    doc = {"asset": {"version": "2.0"},
           "buffers": [{"uri": "data:application/octet-stream;base64,"
                        + base64.b64encode(positions).decode(), "byteLength": 36},
                       {"uri": "missing.bin", "byteLength": 4000}],
           "bufferViews": [{"buffer": 0, "byteLength": 36}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 0]},
                         {"componentType": 5126, "count": 3, "type": "VEC2"}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}}]}],
           "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0}
    path = tmp_path / "t.gltf"
    path.write_text(json.dumps(doc))
    (mesh,) = load(path).objects
    np.testing.assert_array_equal(mesh.uvs, [[0, 1]] * 3)  # zeros, v flipped to 1 - v
    # The missing buffer's declared 4,000 bytes do not count toward the cap (the bound
    # named: the file's and the data: buffer's 36); once it exists, they do.
    doc["accessors"][1]["count"] = 300
    doc["meshes"][0]["primitives"][0]["attributes"] = {"POSITION": 1}
    doc["accessors"][1]["type"] = "VEC3"
    path.write_text(json.dumps(doc))
    with pytest.raises(SceneError, match=r"accessors\[1\]: 3600 bytes of elements without a "
                       rf"buffer view, over the {path.stat().st_size + 36} bytes "):
        load(path)
    (tmp_path / "missing.bin").write_bytes(bytes(4000))
    (mesh,) = load(path).objects  # within the cap now: its zeros are read
    assert len(mesh.vertices) == 300 and not np.any(mesh.vertices)


@pytest.mark.parametrize(("stride", "message"), [
    (4, "bufferViews[0].byteStride: 4 is less than the 12 bytes of accessors[0]'s elements"),
    (14, "bufferViews[0].byteStride: expected a multiple of 4 from 4 to 252, got 14"),
])
def test_a_byte_stride_under_the_element_or_not_a_multiple_of_4_is_named(tmp_path, stride,
                                                                          message):
    # A stride of 4 for float VEC3 (overlapping elements) ended in "every triangle has zero
    # area".
    b = Builder()
    b.node(mesh=b.mesh(CUBE_VERTICES, CUBE_FACES))
    b.doc["bufferViews"][0]["byteStride"] = stride
    path = b.save(tmp_path / "s.glb")
    with pytest.raises(SceneError) as info:
        load(path)
    assert str(info.value) == f"{path.name}: {message}"
