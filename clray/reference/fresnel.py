"""Dielectric reflectance of the oracle (kernels/fresnel.h): the exact unpolarised formula the
kernels use, and Schlick's approximation of the kernels' study variant."""

from __future__ import annotations

import numpy as np


def fresnel_polarised(eta: np.ndarray, cos_i: np.ndarray, cos_t: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(R_s, R_p): the dielectric reflectances of s- and p-polarised light going from IOR n1
    to n2, eta = n1 / n2, at incidence cosine cos_i and refraction cosine cos_t (both >= 0).
    Grazing with cos_i = cos_t = 0 (eta = 1 exactly) is the limit, 1."""
    eta, cos_i, cos_t = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64)
                                              for a in (eta, cos_i, cos_t)))
    ds, dp = eta * cos_i + cos_t, cos_i + eta * cos_t
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = np.where(ds > 0.0, (eta * cos_i - cos_t) / ds, 1.0)
        rp = np.where(dp > 0.0, (cos_i - eta * cos_t) / dp, 1.0)
    return rs * rs, rp * rp


def fresnel_reflectance(eta: np.ndarray, cos_i: np.ndarray, cos_t: np.ndarray) -> np.ndarray:
    """Unpolarised dielectric reflectance (R_s + R_p) / 2."""
    r_s, r_p = fresnel_polarised(eta, cos_i, cos_t)
    return 0.5 * (r_s + r_p)


def fresnel_schlick(eta: np.ndarray, cos_i: np.ndarray, cos_t: np.ndarray) -> np.ndarray:
    """Schlick's approximation R0 + (1 - R0)(1 - c)^5, c the cosine on the less dense side."""
    eta = np.asarray(eta, dtype=np.float64)
    r0 = ((1.0 - eta) / (1.0 + eta)) ** 2
    c = np.where(eta > 1.0, cos_t, cos_i)
    return r0 + (1.0 - r0) * (1.0 - c) ** 5
