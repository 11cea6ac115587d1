"""The [render] table: image size, samples, depth, output encoding and the background."""

from __future__ import annotations

from typing import Any

from clray.scene import limits as L
from clray.scene.assets import Assets
from clray.scene.model import Background, RenderOptions
from clray.scene.texture import COLORSPACES
from clray.scene.values import Values, Vec3

RENDER_KEYS = (
    "width", "height", "spp", "max_depth", "background", "ambient", "seed", "min_weight",
    "linear", "exposure", "png_bits",
)
BACKGROUND_KEYS = {
    "gradient": ("type", "bottom", "top"),
    "image": ("type", "file", "texels", "colorspace"),
}


def parse_render(spec: dict, v: Values, assets: Assets) -> RenderOptions:
    v.keys(spec, "render", RENDER_KEYS, ())
    d = RenderOptions()

    def given(name: str) -> Any:
        return spec.get(name, getattr(d, name))

    # The tables RenderSettings and the command line check their overrides by, too.
    values = {name: v.integer(given(name), f"render.{name}", low, high)
              for name, (low, high) in L.RENDER_INTEGERS.items()}
    values |= {name: v.closed_range(given(name), f"render.{name}", low, high)
               for name, (low, high) in L.RENDER_NUMBERS.items()}
    values |= {name: v.choice(given(name), f"render.{name}", allowed)
               for name, allowed in L.RENDER_CHOICES.items()}
    return RenderOptions(
        **values,
        background=parse_background(given("background"), "render.background", v, assets),
        ambient=v.color(given("ambient"), "render.ambient"),
        linear=v.boolean(given("linear"), "render.linear"),
    )


def parse_background(value: Any, key: str, v: Values, assets: Assets) -> Vec3 | Background:
    """A plain colour, or a gradient or environment image table."""
    if not isinstance(value, dict):
        return v.color(value, key)
    kind = v.kind(value, key, BACKGROUND_KEYS)
    required = BACKGROUND_KEYS[kind] if kind == "gradient" else ("type",)
    v.keys(value, key, BACKGROUND_KEYS[kind], required)
    if kind == "gradient":
        return Background(kind, bottom=v.color(value["bottom"], f"{key}.bottom"),
                          top=v.color(value["top"], f"{key}.top"))
    if "file" in value and "texels" in value:
        raise v.error(key, "give file or texels, not both")
    if "texels" in value:
        if "colorspace" in value:
            raise v.error(f"{key}.colorspace", "texels are linear: give no colorspace")
        return Background(kind, image=assets.texels(value["texels"], f"{key}.texels"))
    if "file" not in value:
        raise v.error(f"{key}.file", "missing required key")
    fkey = f"{key}.file"
    file = assets.base / v.string(value["file"], fkey)
    texels, deep = assets.image(value["file"], fkey)
    colorspace = v.choice(value.get("colorspace", "linear" if deep else "srgb"),
                          f"{key}.colorspace", COLORSPACES)
    if colorspace == "srgb":
        texels = assets.decoded(texels)
    return Background(kind, file=file, colorspace=colorspace, image=texels)
