"""Inverse Hankel transform of radially symmetric frequency responses: R(r) = (1/2pi) int R(q) J0(qr) q dq.

Skin responses R(q) are analytic in q and decay like e^{-q l}, with l the shallowest source depth.
Quadrature in q has two enemies: that slow decay for small r, and the oscillation of J0(q r) for
large r. ``profiles`` removes the first by subtracting the top layer's dipole, whose transform is
known in closed form; this module handles the rest with composite Gauss-Legendre panels whose width
keeps a bounded phase of J0 per panel at the largest radius requested.

The kernel matrix w_j q_j J0(q_j r_i) / 2pi depends only on the radii and the quadrature settings,
so it is built once in NumPy (scipy's J0) and cached; radii must therefore be concrete values.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.special

from .._caching import eager_cache
from .._validate import SkinfitInputError, is_concrete


@dataclasses.dataclass(frozen=True)
class HankelQuadrature:
    """Settings of the q-quadrature (all frequencies in mm^-1, i.e. radians per mm).

    Attributes:
        q_max: upper limit of the integral. The dipole-subtracted skin response falls below 1e-13
            of its peak by q = 100 for the DJ2006 model; 200 leaves margin for thinner epidermis.
        nodes_per_panel: Gauss-Legendre order of each panel.
        phase_per_panel: largest phase span r_max * width (radians) of J0 across one panel.
        max_panel_width: panel width cap, so that the response's own structure is resolved even
            for small radii.
        smallest_panel: width of the first panel at q = 0. Panels double from there up to the
            regular width: R(q) has branch points at q = +-i sigma_tr, close to the real axis for
            weakly absorbing layers (sigma_tr down to ~0.05 mm^-1 in red dermis), and the graded
            panels resolve them.
    """

    q_max: float = 200.0
    nodes_per_panel: int = 16
    phase_per_panel: float = 20.0
    max_panel_width: float = 2.5
    smallest_panel: float = 1e-3

    def nodes(self, max_radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Quadrature nodes q_j (mm^-1) and weights for integrals over [0, q_max]."""
        width = min(self.max_panel_width, self.phase_per_panel / max(max_radius_mm, 1e-12))
        graded = self.smallest_panel * 2.0 ** np.arange(int(np.ceil(np.log2(max(width / self.smallest_panel, 1.0)))))
        start = graded[-1] if graded.size else 0.0
        n_panels = max(int(np.ceil((self.q_max - start) / width)), 1)
        edges = np.concatenate([[0.0], graded[:-1], np.linspace(start, self.q_max, n_panels + 1)])
        x, w = np.polynomial.legendre.leggauss(self.nodes_per_panel)
        half = 0.5 * np.diff(edges)[:, None]
        mid = 0.5 * (edges[1:] + edges[:-1])[:, None]
        return (mid + half * x).ravel(), (half * w).ravel()


def check_radii(radii_mm) -> np.ndarray:
    """Validate radii in mm: concrete, finite, non-negative, 1-D."""
    if not is_concrete(radii_mm):
        raise SkinfitInputError(
            "radii_mm must be concrete values, not traced: close over it or pass it outside jit"
        )
    radii = np.asarray(radii_mm, dtype=float)
    if radii.ndim == 0:
        radii = radii[None]
    if radii.ndim != 1 or radii.size == 0:
        raise SkinfitInputError(f"radii_mm must be a non-empty 1-D array, got shape {radii.shape}")
    if not np.all(np.isfinite(radii)) or np.any(radii < 0):
        raise SkinfitInputError("radii_mm must be finite and >= 0 mm")
    return radii


def inverse_kernel(radii_mm: np.ndarray, quadrature: HankelQuadrature) -> tuple[np.ndarray, np.ndarray]:
    """Nodes q (n_q,) and kernel K (n_q, n_r) with R(r_i) = sum_j R(q_j) K[j, i]."""
    return _inverse_kernel(radii_mm.tobytes(), quadrature)


@eager_cache(maxsize=32)
def _inverse_kernel(radii_bytes: bytes, quadrature: HankelQuadrature):
    radii = np.frombuffer(radii_bytes, dtype=float)
    q, w = quadrature.nodes(float(radii.max()))
    kernel = (w * q / (2.0 * np.pi))[:, None] * scipy.special.j0(q[:, None] * radii[None, :])
    kernel.setflags(write=False)
    return q, kernel


def energy_kernel(radius_mm: float, quadrature: HankelQuadrature) -> tuple[np.ndarray, np.ndarray]:
    """Nodes q and weights w with int_0^a 2 pi r R(r) dr = sum_j R(q_j) w_j, a = ``radius_mm``.

    From int_0^a 2 pi r R(r) dr = a int_0^inf R(q) J1(q a) dq.
    """
    return _energy_kernel(float(radius_mm), quadrature)


@eager_cache(maxsize=32)
def _energy_kernel(radius: float, quadrature: HankelQuadrature):
    q, w = quadrature.nodes(radius)
    weights = w * radius * scipy.special.j1(q * radius)
    weights.setflags(write=False)
    return q, weights
