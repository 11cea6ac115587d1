"""The [[lights]] array: each light's `type` names a kind of the registry (clray.lights), whose
module checks the rest of its keys."""

from __future__ import annotations

from clray.lights import LISTED
from clray.scene.model import Light
from clray.scene.values import Values

# Each `type` a scene file may name -> the keys such a light may have.
LIGHT_KEYS = {kind: ("type", *light.keys[0], *light.keys[1]) for kind, light in LISTED.items()}


def parse_light(spec: dict, key: str, v: Values) -> Light:
    kind = v.kind(spec, key, LIGHT_KEYS)
    light = LISTED[kind]
    v.keys(spec, key, LIGHT_KEYS[kind], light.keys[0])
    color = v.color(spec.get("color", (1.0, 1.0, 1.0)), f"{key}.color")
    return light.parse(spec, key, color, v)
