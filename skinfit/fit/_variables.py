"""What a spectral fit can vary: the skin parameters plus the terms real measurements need.

Each variable has a physical range; the solver works on an unbounded variable u with
value = low + (high - low) (1 + sin u) / 2 (the MINUIT transform), so every iterate stays inside its
range. Unlike a logistic map, a solution on a bound (common for real spectra, e.g. no eumelanin) is
an ordinary quadratic minimum in u, at u = +-pi/2, so the solver converges there instead of drifting
towards infinity. Priors (``skinfit.model.PopulationPrior``) live in other coordinates, where the bounds
are infinitely far: log for concentrations and lengths, logit for fractions (``prior_coordinate``).

The measurement model is

    measured(lambda) = calibration_scale * (S[diffuse](lambda) + specular_offset)

where ``diffuse`` is the skin model's diffuse reflectance (``skinfit.SkinModel``; with
``blood_oxygenation``, ``epidermis_thickness_mm``, ``scattering_scale`` and ``carotene_umol_per_l``
overriding the model's constants when they are free or fixed), or, with a finite measurement port,
the part of it that re-emerges within the port (``captured_reflectance``); S is the instrument's
slit: a triangle of full width at half maximum ``bandwidth_nm`` (identity without one).
For an instrument that includes the specular reflection (incidence theta, e.g. 8 degrees for
a d/8 sphere in SCI mode), the surface layer replaces the entry Fresnel factor:

    diffuse(lambda) = rho(theta) + (1 - rho(theta)) R12(lambda)

with rho = oil x the lobe's directional albedo (``skinfit.model``), so ``oil`` can be fitted.

The constants of the skin model and the fixed values are array leaves of ``MeasurementModel``: a
fit compiles once per free set and instrument, never per value.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._caching import eager_cache
from ..colorimetry import xyz_to_lab, xyz_weights
from ..model import (
    SURFACE_ROUGHNESS,
    Diffusion,
    HankelQuadrature,
    SkinModel,
    SkinParams,
    captured_of_layers,
    energy_kernel,
    lobe_albedo,
    normal_fresnel_reflectance,
    skin_stack_reflectance,
)


@dataclasses.dataclass(frozen=True)
class FitVariable:
    """One fit variable: its range, its value when fixed, its prior coordinate and what it means.

    ``default`` None: no default (a chromophore must be free or given); ``MODEL``: the skin
    model's own constant.
    """

    low: float
    high: float
    default: float | str | None
    doc: str
    prior: str = "linear"  # prior coordinate: "log", "logit" or "linear"


#: ``FitVariable.default`` of variables that are constants of the skin model.
MODEL = "model"

VARIABLES: dict[str, FitVariable] = {
    "melanin": FitVariable(0.0, 1.0, None, "C_m, epidermal melanin volume fraction", "log"),
    "melanin_blend": FitVariable(0.0, 1.0, None, "beta_m, eumelanin fraction of the melanin", "logit"),
    "haemoglobin": FitVariable(0.0, 1.0, None, "C_h, dermal blood volume fraction", "log"),
    "blood_oxygenation": FitVariable(0.0, 1.0, MODEL, "HbO2 fraction of the blood (the model's constant)", "logit"),
    "epidermis_thickness_mm": FitVariable(0.01, 1.0, MODEL, "epidermis thickness in mm (the model's constant)", "log"),
    "scattering_scale": FitVariable(0.2, 5.0, 1.0, "factor on the reduced scattering of both layers (1: the model's)", "log"),
    "carotene_umol_per_l": FitVariable(0.0, 300.0, MODEL, "epidermal beta-carotene, umol/L (the model's constant)", "log"),
    "specular_offset": FitVariable(
        0.0, 0.3, 0.0, "additive surface reflection, for hemispherical instruments that include it (~0.028)"
    ),
    "calibration_scale": FitVariable(0.5, 2.0, 1.0, "multiplicative calibration of the instrument", "log"),
    "oil": FitVariable(
        0.0, 2.0, 0.3, "surface lobe scale rho_s (DJ2006 about 0-1; 1 is a clean rough surface of the model's surface "
        "index); only for measurements that include the specular part (specular_included_deg); 0.3 in the DJ2006 scenes",
        "logit",
    ),
}

CHROMOPHORES = ("melanin", "melanin_blend", "haemoglobin")

#: Variables that override the skin model's constant of the same name.
MODEL_FIELDS = ("blood_oxygenation", "epidermis_thickness_mm", "carotene_umol_per_l")


def model_constant(skin: SkinModel, name: str) -> float:
    """The model's value of the fit variable ``name`` (one of ``MODEL_FIELDS``; its mean if it varies)."""
    return float(np.mean(np.asarray(getattr(skin, name))))

#: Where a free variable starts when no table covers it (and it has no fixed value).
STARTS = {"specular_offset": 0.02, "oil": 0.3, "carotene_umol_per_l": 5.0}


def to_unbounded(name: str, value):
    """u in [-pi/2, pi/2] such that ``from_unbounded(name, u) == value``."""
    var = VARIABLES[name]
    frac = np.clip((np.asarray(value, dtype=float) - var.low) / (var.high - var.low), 0.0, 1.0)
    return np.arcsin(2.0 * frac - 1.0)


def from_unbounded(name: str, u):
    """Physical value of variable ``name`` from its unbounded coordinate ``u`` (NumPy in, NumPy out:
    eager JAX on results would compile each primitive for every new batch shape)."""
    var = VARIABLES[name]
    xp = np if isinstance(u, (np.ndarray, float)) else jnp
    return var.low + (var.high - var.low) * 0.5 * (1.0 + xp.sin(u))


def prior_coordinate(name: str, value):
    """The coordinate in which a prior on ``name`` is Gaussian: log, logit of the range fraction, or
    the value itself. Finite at the bounds and differentiable everywhere: the fraction is squeezed
    affinely by 1e-9 of the range (a clip there would zero the prior's gradient, and a fit that the
    data push to a bound would then stay on it, unopposed)."""
    var = VARIABLES[name]
    xp = jnp if isinstance(value, jax.Array) else np
    span = var.high - var.low
    if var.prior == "log":
        return xp.log(xp.maximum(value, 0.0) + _PRIOR_FLOOR * span)
    if var.prior == "logit":
        f = _PRIOR_FLOOR + (1.0 - 2.0 * _PRIOR_FLOOR) * xp.clip((value - var.low) / span, 0.0, 1.0)
        return xp.log(f) - xp.log1p(-f)
    return value


_PRIOR_FLOOR = 1e-9


class MeasurementModel(eqx.Module):
    """The measured spectrum as a function of the free variables.

    Static (one compilation each): the free and fixed names, the port, the specular geometry, the
    instrument's bandwidth and whether the colour and prior terms are on. Traced: the fixed values
    and the skin model's constants.

    Attributes:
        free: names of the free variables, in the order of the unbounded vector u.
        fixed_names, fixed_values: the other variables that are set (model constants not named
            here keep the skin model's value).
        skin: the ``SkinModel``.
        port_radius_mm: radius of the measurement port, or None for an infinite port.
        specular_included_deg: incidence angle of a measurement that includes the specular part.
        bandwidth_nm: full width at half maximum of the instrument's triangular slit, or None.
        colour_weight: weight of the CIELAB difference (D65) in the residual, per unit of Delta E.
        use_prior: add the skin model's population prior to the residual.
    """

    free: tuple[str, ...] = eqx.field(static=True)
    fixed_names: tuple[str, ...] = eqx.field(static=True)
    fixed_values: Float[Array, " n_fixed"]
    skin: SkinModel
    port_radius_mm: float | None = eqx.field(static=True, default=None)
    specular_included_deg: float | None = eqx.field(static=True, default=None)
    bandwidth_nm: float | None = eqx.field(static=True, default=None)
    colour_weight: float = eqx.field(static=True, default=0.0)
    use_prior: bool = eqx.field(static=True, default=False)

    def as_diffusion(self) -> "MeasurementModel":
        """The same measurement through the diffusion model (the start of a transport fit)."""
        new = Diffusion(self.skin.method.profile_adding)
        return eqx.tree_at(lambda m: m.skin, self, self.skin.replace(method=new))

    @property
    def static_key(self):
        """What identifies the compiled programs of this measurement (everything but array values)."""
        dynamic, static = eqx.partition(self, eqx.is_array)
        leaves, treedef = jax.tree_util.tree_flatten(static)
        return treedef, tuple(leaves), jax.tree_util.tree_structure(dynamic)

    def values(self, u) -> dict:
        """The set variables (free from u, fixed ones) as a dict of arrays of u's batch shape (NumPy
        for NumPy u)."""
        values = {name: from_unbounded(name, u[..., i]) for i, name in enumerate(self.free)}
        return self._with_fixed(values, u)

    def values_of_free(self, theta) -> dict:
        """``values`` from the physical values ``theta`` (..., n_free) of the free variables."""
        return self._with_fixed({name: theta[..., i] for i, name in enumerate(self.free)}, theta)

    def _with_fixed(self, values, like):
        xp = np if isinstance(like, np.ndarray) else jnp  # NumPy stays NumPy (no eager JAX)
        fixed = xp.asarray(self.fixed_values, like.dtype)
        for i, name in enumerate(self.fixed_names):
            values[name] = xp.broadcast_to(fixed[i], like.shape[:-1])
        return values

    def spectrum(self, u, wavelengths_nm):
        """Model spectrum at ``wavelengths_nm`` for the unbounded vector u of shape (..., n_free)."""
        return self.spectrum_of_values(self.values(u), wavelengths_nm, u.dtype)

    def spectrum_of_free(self, theta, wavelengths_nm):
        """Model spectrum for the physical values ``theta`` (..., n_free) of the free variables."""
        return self.spectrum_of_values(self.values_of_free(theta), wavelengths_nm, theta.dtype)

    def spectrum_of_values(self, v: dict, wavelengths_nm, dtype):
        """Model spectrum from a dict of the variables' physical values."""
        lam_out = np.asarray(wavelengths_nm, dtype=float)
        lam, slit = _slit(tuple(lam_out.tolist()), self.bandwidth_nm)
        lam = jnp.asarray(lam, dtype)
        skin = self.skin.replace(**{n: v[n] for n in MODEL_FIELDS if n in v})
        params = SkinParams(v["melanin"], v["melanin_blend"], v["haemoglobin"])
        one = jnp.ones(jnp.shape(v["melanin"]), dtype)
        layers = skin.layers(params, lam, scattering_scale=v.get("scattering_scale", one))
        if self.port_radius_mm is None:
            diffuse = skin_stack_reflectance(*layers, skin.method)
        else:
            q, weights = energy_kernel(self.port_radius_mm, _PORT_QUADRATURE)
            diffuse = captured_of_layers(layers, jnp.asarray(self.port_radius_mm, dtype), q, weights, skin.method)
        if self.specular_included_deg is not None:
            theta = np.radians(self.specular_included_deg)
            direction = jnp.asarray([np.sin(theta), 0.0, np.cos(theta)], dtype)
            rho = v["oil"][..., None] * lobe_albedo(direction, SURFACE_ROUGHNESS, jnp.asarray(skin.surface_ior, dtype)[..., None])
            r12 = diffuse / (1.0 - normal_fresnel_reflectance(jnp.asarray(skin.ior, dtype)[..., None]))  # undo the entry Fresnel
            diffuse = rho + (1.0 - rho) * r12
        if slit is not None:
            diffuse = diffuse @ jnp.asarray(slit, dtype).T
        scale = v.get("calibration_scale", one)[..., None]
        return scale * (diffuse + v.get("specular_offset", 0.0 * one)[..., None])

    def residual(self, u, target, wavelengths_nm, weights):
        """The least-squares residual of one fit at u: the weighted spectrum (m rows), then (where they
        are on) the colour term (``colour_rows``) and the prior's rows."""
        return self.residual_of_evaluation(self.evaluation(u, wavelengths_nm), target, wavelengths_nm, weights)

    def residual_of_free(self, theta, target, wavelengths_nm, weights):
        """``residual`` at the physical values ``theta`` of the free variables."""
        return self.residual_of_evaluation(self.evaluation_of_free(theta, wavelengths_nm), target, wavelengths_nm, weights)

    @property
    def colour_rows(self) -> int:
        """Rows of the colour term in ``residual`` (CIELAB L*, a*, b*), after the spectrum's."""
        return 3 if self.colour_weight else 0

    @property
    def prior_rows(self) -> int:
        """Rows of the prior term in ``residual``, after the colour rows."""
        return sum(name in self.free for name in self.skin.prior.names) if self.use_prior else 0

    # The residual in two parts: the costly evaluation (the model spectrum, and the prior's rows) and
    # the cheap rest (weights, colour term). Solvers that differentiate the evaluation alone and form
    # the residual's Jacobian from its Jacobian (``linearised_residual``) in a later step of a loop
    # save about a quarter of a DJ2006 iteration on CPU: differentiated in one piece, XLA copies the
    # multipole's last fusion into the colour term's sum over wavelengths, so it runs twice.
    # (Named like ``spectrum``, ``spectrum_of_free`` and ``spectrum_of_values``.)
    def evaluation(self, u, wavelengths_nm):
        """The model spectrum (m,) at the unbounded vector u, then the prior's rows (where it is on)."""
        return self.evaluation_of_values(self.values(u), wavelengths_nm, u.dtype)

    def evaluation_of_free(self, theta, wavelengths_nm):
        """``evaluation`` at the physical values ``theta`` (..., n_free) of the free variables."""
        return self.evaluation_of_values(self.values_of_free(theta), wavelengths_nm, theta.dtype)

    def evaluation_of_values(self, values: dict, wavelengths_nm, dtype):
        """``evaluation`` from a dict of the variables' physical values."""
        spectrum = self.spectrum_of_values(values, wavelengths_nm, dtype)
        return jnp.concatenate([spectrum, self.prior_residual(values)], axis=-1) if self.use_prior else spectrum

    def residual_of_evaluation(self, evaluation, target, wavelengths_nm, weights):
        """The residual from an ``evaluation``: weighted spectrum, colour term, prior rows."""
        m = target.shape[-1]
        spectrum = evaluation[..., :m]
        parts = [weights * (spectrum - target)]
        if self.colour_rows:
            xyz = jnp.asarray(_xyz_weights(tuple(np.asarray(wavelengths_nm, dtype=float).tolist())), spectrum.dtype)
            lab = lambda spectra: xyz_to_lab(spectra @ xyz.T, white_xyz=xyz.sum(axis=-1))  # noqa: E731 - the grid's own white
            parts.append(self.colour_weight * (lab(spectrum) - lab(target)))
        parts.append(evaluation[..., m:])
        return jnp.concatenate(parts, axis=-1)

    def linearised_residual(self, evaluation, jacobian, target, wavelengths_nm, weights):
        """(residual, its Jacobian) from one ``evaluation`` (k,) and its Jacobian (k, n) with
        respect to any n coordinates: the chain rule through the cheap rest, one JVP per column."""
        rest = lambda e: self.residual_of_evaluation(e, target, wavelengths_nm, weights)  # noqa: E731
        residual, tangent = jax.linearize(rest, evaluation)
        return residual, jax.vmap(tangent, in_axes=1, out_axes=1)(jacobian)

    def prior_residual(self, values: dict):
        """noise_rms (z - mean) / sd for each free variable the prior covers (z: prior coordinate)."""
        prior = self.skin.prior
        rows = []
        for i, name in enumerate(prior.names):
            if name in self.free:
                z = prior_coordinate(name, values[name])
                rows.append(prior.noise_rms * (z - prior.mean[i]) / prior.sd[i])
        like = values[self.free[0]]
        return jnp.stack(rows, axis=-1) if rows else jnp.zeros(jnp.shape(like) + (0,), like.dtype)


def stationarity(free, theta, gradient, cost):
    """First-order optimality in physical coordinates, as a fraction of the cost.

    The largest change of the cost that a full-range move of one variable would give to first
    order, counting only moves that stay inside the box (a variable on a bound whose gradient
    pushes outward is optimal there), divided by the cost. Converged fits have ~0.
    """
    low = jnp.array([VARIABLES[n].low for n in free])
    high = jnp.array([VARIABLES[n].high for n in free])
    span = high - low
    at_low = theta - low <= 1e-6 * span
    at_high = high - theta <= 1e-6 * span
    projected = jnp.where(at_low, jnp.minimum(gradient, 0.0), jnp.where(at_high, jnp.maximum(gradient, 0.0), gradient))
    return jnp.max(jnp.abs(projected) * span) / jnp.maximum(cost, 1e-300)


@eager_cache(maxsize=32)
def _slit(wavelengths: tuple, bandwidth_nm: float | None):
    """Wavelengths to evaluate and the (m, k) matrix that applies a triangular slit of FWHM
    ``bandwidth_nm`` centred on each output wavelength (None: the grid itself, no matrix).

    The triangle (support +-FWHM) is integrated by the trapezoid rule on sub-steps of FWHM / 4:
    7 nodes per output wavelength, shared between neighbours on a regular grid.
    """
    lam = np.asarray(wavelengths)
    if bandwidth_nm is None:
        return lam, None
    h = float(bandwidth_nm) / 4.0
    offsets = h * np.arange(-3, 4)
    shape = 1.0 - np.abs(offsets) / float(bandwidth_nm)
    nodes = np.unique(np.round((lam[:, None] + offsets[None, :]).ravel(), 9))
    matrix = np.zeros((lam.size, nodes.size))
    for i, centre in enumerate(lam):
        at = np.searchsorted(nodes, np.round(centre + offsets, 9))
        matrix[i, at] += shape / shape.sum()
    return nodes, matrix


@eager_cache(maxsize=32)
def _xyz_weights(wavelengths: tuple) -> np.ndarray:
    """CIE 1931 XYZ weights under D65 for the grid, normalised so the perfect white has Y = 1."""
    return xyz_weights(np.asarray(wavelengths))


def _port_quadrature():
    # The port integral needs less than a full profile: 1e-9 of the reflectance is ample for fits.
    return HankelQuadrature(q_max=120.0, nodes_per_panel=12)


_PORT_QUADRATURE = _port_quadrature()
