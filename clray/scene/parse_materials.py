"""The [materials] table, materials given inline, and their textures."""

from __future__ import annotations

from typing import Any

from clray.scene import limits as L
from clray.scene.assets import Assets
from clray.scene.model import Material, Texture
from clray.scene.texture import COLORSPACES
from clray.scene.values import Values, key_path, show, show_defined

MATERIAL_KEYS = (
    "color",
    "ambient",
    "diffuse",
    "specular",
    "shininess",
    "reflect",
    "transmit",
    "ior",
    "texture",
    "fresnel",
    "emission",
)
TEXTURE_KEYS = {
    "checker": ("type", "size", "color2", "blend"),
    "image": ("type", "file", "texels", "repeat", "blend", "colorspace"),
}


class MaterialTable:
    """The scene's materials in order: the named ones of [materials], then those given inline
    and the default, added the first time an object names them."""

    def __init__(self, spec: dict, v: Values, assets: Assets) -> None:
        self.v, self.assets = v, assets
        self.materials: list[Material] = []
        self.named: dict[str, int] = {}
        self.default: int | None = None
        # Materials of OBJ files' libraries, by (library identity, name): added once each.
        self.from_libraries: dict[tuple[tuple[int, int], str], int] = {}
        for name, value in spec.items():
            key = key_path("materials", name)
            self.named[name] = len(self.materials)
            self.materials.append(parse_material(v.table(value, key), key, name, v, assets))

    def add(self, material: Material) -> int:
        """Append a material (one of an OBJ file's libraries): its index."""
        self.materials.append(material)
        return len(self.materials) - 1

    def for_object(self, spec: dict, key: str) -> int:
        """The index of an object's `material`, or of the default material if it has none."""
        if "material" not in spec:
            if self.default is None:
                self.default = len(self.materials)
                self.materials.append(Material(name="(default)"))
            return self.default
        return self.ref(spec["material"], f"{key}.material")

    def ref(self, value: Any, key: str) -> int:
        """The index of a material named, or given as an inline table."""
        if isinstance(value, str):
            if value not in self.named:
                raise self.v.error(key, f"unknown material {show(value)} (defined: "
                                   f"{show_defined(list(self.named))})")
            return self.named[value]
        if isinstance(value, dict):
            self.materials.append(parse_material(value, key, key, self.v, self.assets))
            return len(self.materials) - 1
        raise self.v.error(
            key, f"expected a material name or an inline table, got {show(value)}"
        )


def parse_material(spec: dict, key: str, name: str, v: Values, assets: Assets) -> Material:
    v.keys(spec, key, MATERIAL_KEYS, ())
    d = Material(name=name)

    def coefficient(field: str, high: float) -> float:
        return v.bounded(spec.get(field, getattr(d, field)), f"{key}.{field}", 0, high)

    texture = None
    if "texture" in spec:
        tkey = f"{key}.texture"
        texture = parse_texture(v.table(spec["texture"], tkey), tkey, v, assets)
    low_ior, high_ior = L.IOR_RANGE
    fresnel = v.boolean(spec.get("fresnel", d.fresnel), f"{key}.fresnel")
    reflect = coefficient("reflect", L.MAX_BOUNCE_WEIGHT)
    transmit = coefficient("transmit", L.MAX_BOUNCE_WEIGHT)
    # With Fresnel, reflect + transmit leave the surface in all (docs/rendering.md).
    if fresnel and reflect + transmit > L.MAX_BOUNCE_WEIGHT:
        raise v.error(f"{key}.fresnel", f"needs reflect + transmit <= "
                      f"{L.MAX_BOUNCE_WEIGHT:g}, got {reflect:g} + {transmit:g}")
    return Material(
        name=name,
        color=v.color(spec.get("color", d.color), f"{key}.color"),
        ambient=coefficient("ambient", L.MAX_WEIGHT),
        diffuse=coefficient("diffuse", L.MAX_WEIGHT),
        emission=v.color(spec.get("emission", d.emission), f"{key}.emission"),
        specular=coefficient("specular", L.MAX_WEIGHT),
        shininess=coefficient("shininess", L.MAX_SHININESS),
        reflect=reflect,
        transmit=transmit,
        ior=v.bounded(spec.get("ior", d.ior), f"{key}.ior", low_ior, high_ior),
        texture=texture,
        fresnel=fresnel,
    )


def parse_texture(spec: dict, key: str, v: Values, assets: Assets,
                  written: str | None = None) -> Texture:
    """A texture table. `written`: the image file's name as the file that refers to it writes
    it (an MTL file's map_Kd), which messages name instead of spec's joined path."""
    kind = v.kind(spec, key, TEXTURE_KEYS)
    v.keys(spec, key, TEXTURE_KEYS[kind], ("type",))
    d = Texture(kind=kind)
    blend = v.closed_range(spec.get("blend", d.blend), f"{key}.blend", 0, 1)
    if kind == "checker":
        return Texture(
            kind=kind,
            size=v.length(spec.get("size", d.size), f"{key}.size"),
            color2=v.color(spec.get("color2", d.color2), f"{key}.color2"),
            blend=blend,
        )
    rkey = f"{key}.repeat"
    j, k = v.numbers(spec.get("repeat", d.repeat), rkey, 2)
    if min(j, k) <= 0:
        raise v.error(rkey, f"must be > 0, got {show(spec['repeat'])}")
    if min(j, k) < L.MIN_LENGTH:
        raise v.error(rkey, f"must be >= {L.MIN_LENGTH:g}, got {show(spec['repeat'])}")
    if "file" in spec and "texels" in spec:
        raise v.error(key, "give file or texels, not both")
    if "file" not in spec and "texels" not in spec:
        raise v.error(f"{key}.file", "missing required key")
    if "texels" in spec:
        if "colorspace" in spec:
            raise v.error(f"{key}.colorspace", "texels are linear: give no colorspace")
        texels = assets.texels(spec["texels"], f"{key}.texels")
        return Texture(kind=kind, repeat=(j, k), blend=blend, image=texels)
    fkey = f"{key}.file"
    file = assets.base / v.string(spec["file"], fkey)
    texels, deep = assets.image(spec["file"], fkey, written)
    # The file's values are sRGB-encoded unless it says otherwise: by default 8-bit images
    # are (as cameras and paint programs write them), 16-bit and float ones are linear.
    colorspace = v.choice(
        spec.get("colorspace", "linear" if deep else "srgb"), f"{key}.colorspace",
        COLORSPACES,
    )
    if colorspace == "srgb":
        texels = assets.decoded(texels)
    return Texture(
        kind=kind, file=file, repeat=(j, k), blend=blend, colorspace=colorspace, image=texels
    )
