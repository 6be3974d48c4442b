"""Independent reference implementations for the tests (NumPy, written from model notes, not from skinfit).

* ``image_sum_profiles``: the DJ2005 real-space multipole (model notes 5.1) with many dipole pairs.
* ``image_sum_transfer``: the same image series in q-space, term by term (model notes 5.2).
* ``forward_hankel``: 2 pi int f(r) J0(q r) r dr by composite Gauss-Legendre in r.
* ``fft_profile``: the 2-D FFT recipe of model notes 5.3 item 4.
"""

from __future__ import annotations

import numpy as np
import scipy.special


def f_dr(eta):
    if eta >= 1.0:
        return -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta
    return -0.4399 + 0.7099 / eta - 0.3319 / eta**2 + 0.0636 / eta**3


def slab_geometry(sigma_a, sigma_s, d, eta_top, eta_bottom):
    sigma_t = sigma_a + sigma_s
    diff = 1.0 / (3.0 * sigma_t)
    a_top = (1 + f_dr(eta_top)) / (1 - f_dr(eta_top))
    a_bot = (1 + f_dr(eta_bottom)) / (1 - f_dr(eta_bottom))
    return dict(
        albedo=sigma_s / sigma_t,
        sigma_tr=np.sqrt(3.0 * sigma_a * sigma_t),
        l=1.0 / sigma_t,
        zb0=2.0 * a_top * diff,
        zbd=2.0 * a_bot * diff,
        d=d,
    )


def _image_depths(g, n):
    i = np.arange(-n, n + 1)
    span = g["d"] + g["zb0"] + g["zbd"]
    z_r = 2 * i * span + g["l"]
    z_v = 2 * i * span - g["l"] - 2 * g["zb0"]
    return z_r, z_v


def image_sum_profiles(sigma_a, sigma_s, d, eta_top, eta_bottom, r, n=400):
    """Real-space R(r), T(r) in mm^-2 from 2n+1 dipole pairs (DJ2005, model notes 5.1)."""
    g = slab_geometry(sigma_a, sigma_s, d, eta_top, eta_bottom)
    z_r, z_v = _image_depths(g, n)
    r = np.asarray(r, dtype=float)[..., None]
    s = g["sigma_tr"]

    def term(z):
        dist = np.sqrt(r**2 + z**2)
        return z * (1 + s * dist) * np.exp(-s * dist) / dist**3

    refl = g["albedo"] / (4 * np.pi) * np.sum(term(z_r) - term(z_v), axis=-1)
    trans = g["albedo"] / (4 * np.pi) * np.sum(term(d - z_r) - term(d - z_v), axis=-1)
    return refl, trans


def image_sum_transfer(sigma_a, sigma_s, d, eta_top, eta_bottom, q, n=2000):
    """R(q), T(q) of the image series summed term by term: (alpha'/2) sum sgn(z) e^{-k|z|}."""
    g = slab_geometry(sigma_a, sigma_s, d, eta_top, eta_bottom)
    z_r, z_v = _image_depths(g, n)
    k = np.sqrt(g["sigma_tr"] ** 2 + np.asarray(q, dtype=float)[..., None] ** 2)

    def term(z):
        return np.sign(z) * np.exp(-k * np.abs(z))

    refl = 0.5 * g["albedo"] * np.sum(term(z_r) - term(z_v), axis=-1)
    trans = 0.5 * g["albedo"] * np.sum(term(d - z_r) - term(d - z_v), axis=-1)
    return refl, trans


def forward_hankel(func, q, r_max, n_panels=2000, order=16, r_min=1e-7):
    """2 pi int_0^r_max f(r) J0(q r) r dr with log-spaced + uniform Gauss-Legendre panels."""
    edges = np.unique(np.concatenate([[0.0], np.geomspace(r_min, r_max, n_panels // 2), np.linspace(0, r_max, n_panels // 2)]))
    x, w = np.polynomial.legendre.leggauss(order)
    half = 0.5 * np.diff(edges)[:, None]
    mid = 0.5 * (edges[1:] + edges[:-1])[:, None]
    r = (mid + half * x).ravel()
    weights = (half * w).ravel()
    values = func(r)
    q = np.atleast_1d(np.asarray(q, dtype=float))
    return np.array([2 * np.pi * np.sum(weights * values * scipy.special.j0(qq * r) * r) for qq in q])


def fft_profile(transfer, n=2048, dx=0.02):
    """R on the grid x = j dx (j = 0..n/2) along an axis, from a 2-D inverse FFT of R(|q|)."""
    freq = 2 * np.pi * np.fft.fftfreq(n, dx)
    q = np.sqrt(freq[:, None] ** 2 + freq[None, :] ** 2)
    spatial = np.real(np.fft.ifft2(transfer(q))) / dx**2
    return np.arange(n // 2) * dx, spatial[0, : n // 2]


def chandrasekhar_h(albedo, mu, nodes=200, iterations=2000):
    """Chandrasekhar's H-function for isotropic scattering with single-scattering albedo ``albedo``
    at cosines ``mu``, by iterating 1/H(mu) = sqrt(1 - a) + (a/2) int_0^1 mu' H(mu') / (mu + mu') dmu'
    on Gauss-Legendre nodes."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    nodes_mu, weights = 0.5 * (x + 1), 0.5 * w
    h = np.ones(nodes)
    root = np.sqrt(1 - albedo)
    for _ in range(iterations):
        new = 1.0 / (root + 0.5 * albedo * np.sum(weights * nodes_mu * h / (nodes_mu[:, None] + nodes_mu), axis=1))
        if np.max(np.abs(new - h)) < 1e-15:
            h = new
            break
        h = new
    mu = np.atleast_1d(np.asarray(mu, dtype=float))
    return 1.0 / (root + 0.5 * albedo * np.sum(weights * nodes_mu * h / (mu[:, None] + nodes_mu), axis=1))


def semi_infinite_isotropic_albedo(albedo, mu0=1.0):
    """Exact diffuse reflectance of an index-matched semi-infinite isotropic medium for a beam at
    cosine ``mu0`` (Chandrasekhar): 1 - H(mu0) sqrt(1 - a)."""
    return float(1.0 - chandrasekhar_h(albedo, mu0)[0] * np.sqrt(1 - albedo))
