"""Materials and textures of the oracle (kernels/texture.h): a surface's colour at a hit."""

from __future__ import annotations

import numpy as np

from clray.scene.model import Material, Texture
from clray.vectors import vec


class MaterialTable:
    """The scene's materials as columns, indexed by material number."""

    def __init__(self, materials: tuple[Material, ...]) -> None:
        self.materials = materials
        self.color = np.array([m.color for m in materials], dtype=np.float64).reshape(-1, 3)
        self.emission = np.array([m.emission for m in materials],
                                 dtype=np.float64).reshape(-1, 3)

        def column(name: str) -> np.ndarray:
            return np.array([getattr(m, name) for m in materials], dtype=np.float64)

        self.ambient = column("ambient")
        self.diffuse = column("diffuse")
        self.specular = column("specular")
        self.shininess = column("shininess")
        self.reflect = column("reflect")
        self.transmit = column("transmit")
        self.ior = column("ior")
        self.fresnel = np.array([m.fresnel for m in materials], dtype=bool)
        self.filter = self.transmit[:, None] * self.color  # shadow filter per crossing


def wrap01(x: np.ndarray) -> np.ndarray:
    """x wrapped into [0, 1) (kernels/texture.h): x - floor(x), but 0 where that rounds to 1
    (a tiny negative x) and where x is not finite (a degenerate (u, v)), so that it never
    becomes a wild index."""
    with np.errstate(invalid="ignore"):
        f = x - np.floor(x)
    return np.where(np.isfinite(x) & (f < 1.0), f, 0.0)


def image_texel(
    image: np.ndarray, u: np.ndarray, v: np.ndarray, repeat: tuple[float, float],
    ends_apart: np.ndarray | bool = False,
) -> np.ndarray:
    """Bilinear, wrapping lookup of an (H, W, 3) image (row 0 at the top) at (u, v). Where
    ends_apart (v runs pole to pole or rim to rim: v_ends_apart), v * repeat is first held
    within half a texel row of 0 and of repeat, so the ends do not blend the first row with
    the last."""
    texels = np.asarray(image, dtype=np.float64)
    height, width = texels.shape[:2]
    j, k = repeat
    uj, vk = u * j, v * k
    # fmax/fmin as the kernel's: a NaN takes the low bound, crossed bounds give the high one.
    half_row = 0.5 / height
    vk = np.where(ends_apart, np.fmin(np.fmax(vk, half_row), k - half_row), vk)
    s = wrap01(uj) * width - 0.5
    t = (1.0 - wrap01(vk)) * height - 0.5
    x0, y0 = np.floor(s), np.floor(t)
    fx, fy = (s - x0)[:, None], (t - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    x1, y1 = (x0 + 1) % width, (y0 + 1) % height
    x0, y0 = x0 % width, y0 % height
    return (
        (1 - fx) * (1 - fy) * texels[y0, x0]
        + fx * (1 - fy) * texels[y0, x1]
        + (1 - fx) * fy * texels[y1, x0]
        + fx * fy * texels[y1, x1]
    )


def checker_texel(
    texture: Texture, color: np.ndarray, p: np.ndarray, facing_normal: np.ndarray
) -> np.ndarray:
    """The 3D checker: `color` on even cells of q = p - size/4 * n_f, else texture.color2."""
    q = p - 0.25 * texture.size * facing_normal
    cells = np.sum(np.floor(q / texture.size), axis=-1)
    even = (cells % 2 == 0)[:, None]
    return np.where(even, color, vec(texture.color2))


def surface_color(
    mats: MaterialTable, material: np.ndarray, p: np.ndarray, uv: np.ndarray, ngf: np.ndarray,
    ends_apart: np.ndarray,
) -> np.ndarray:
    """The material's colour, blended with its texture's texel where it has one (ends_apart:
    SceneHit.ends_apart, for image_texel)."""
    c = mats.color[material]
    for idx, mat in enumerate(mats.materials):
        tex = mat.texture
        m = material == idx
        if tex is None or not m.any():
            continue
        if tex.kind == "checker":
            texel = checker_texel(tex, mats.color[idx], p[m], ngf[m])
        else:
            texel = image_texel(tex.image, uv[m, 0], uv[m, 1], tex.repeat, ends_apart[m])
        c[m] = tex.blend * texel + (1.0 - tex.blend) * mats.color[idx]
    return c
