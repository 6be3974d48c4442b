"""The skin model as an object: every constant of the two-layer model and the forward method.

A ``SkinModel`` is an equinox Module, so a pytree: its constants are array leaves that jit traces
(changing a value never recompiles), vmap maps and grad differentiates; only the structure (the
forward method, the chromophores present, the name) is static. Every public function that
evaluates the model takes ``model=`` (default: ``SkinModel.default()``).

From the parameters (``SkinParams``) and the model's constants, at wavelength lambda (nm):

    sigma_a,epi  = C_m [beta_m sigma_em + (1 - beta_m) sigma_pm] + C_he B + c_car sigma_car
                   + (1 - C_m - C_he) k sigma_base
    sigma_a,derm = C_h B + (1 - C_h) k sigma_base
    B            = P(sigma_blood, R) sigma_blood,   sigma_blood = gamma sigma_oxy + (1 - gamma) sigma_deoxy
    sigma_s'     = a_mie (lambda / 500)^-b_mie + a_ray (lambda / 500)^-4          (each layer its own law)

with C_he = epidermal_blood x C_h (blood in the epidermis, or in a thin vascular layer folded into
it), P the pigment-packaging factor of blood in vessels of radius R (``chromophores.packaging_factor``),
c_car the epidermal beta-carotene concentration and k the baseline scale. DJ2006 is the special case
C_he = 0, R = 0, c_car = 0, k = 1 and the dermis scattering half the epidermis's
(``SkinModel.dj2006()``). The layers then go to the forward method: the DJ2005 multipole with
frequency-domain adding (``Diffusion``) or exact 1-D radiative transport (``Transport``:
adding-doubling, tabulated or direct).
"""

from __future__ import annotations

import hashlib
import importlib.resources
import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._caching import eager_cache
from .._validate import SkinfitInputError, as_float_array, check_range, is_concrete
from . import _chromophores as chrom
from ._layers import BLOOD_OXYGENATION, EPIDERMIS_THICKNESS_MM, SKIN_IOR, Layer
from ._methods import Diffusion, ForwardMethod, method_from_dict
from ._params import SkinParams
from ._transport_table import TransportTable

#: Wavelength (nm) at which the scattering laws' amplitudes are given.
REFERENCE_WAVELENGTH_NM = 500.0

# DJ2006's epidermal law 14.74 lambda^-0.22 + 2.2e11 lambda^-4 (mm^-1, lambda in nm) at 500 nm.
_DJ2006_MIE_MM = 14.74 * REFERENCE_WAVELENGTH_NM**-0.22
_DJ2006_RAYLEIGH_MM = 2.2e11 * REFERENCE_WAVELENGTH_NM**-4.0


def _field(name, value):
    return as_float_array(name, value)


class ScatteringLaw(eqx.Module):
    """Reduced scattering of a layer, sigma_s'(lambda) = a_mie (lambda/500)^-b + a_ray (lambda/500)^-4 (mm^-1).

    Attributes:
        mie_mm: Mie part at 500 nm, mm^-1.
        mie_power: its power b (DJ2006: 0.22).
        rayleigh_mm: Rayleigh part at 500 nm, mm^-1.
    """

    mie_mm: Float[Array, "..."]
    mie_power: Float[Array, "..."]
    rayleigh_mm: Float[Array, "..."]

    def __init__(self, mie_mm, mie_power, rayleigh_mm):
        self.mie_mm = _field("mie_mm", mie_mm)
        self.mie_power = _field("mie_power", mie_power)
        self.rayleigh_mm = _field("rayleigh_mm", rayleigh_mm)

    def __call__(self, wavelengths_nm: ArrayLike) -> Float[Array, "..."]:
        x = jnp.asarray(wavelengths_nm) / REFERENCE_WAVELENGTH_NM
        return self.mie_mm * x ** -self.mie_power + self.rayleigh_mm * x**-4.0

    def scaled(self, factor) -> "ScatteringLaw":
        """The same law with both parts times ``factor``."""
        return eqx.tree_at(lambda s: (s.mie_mm, s.rayleigh_mm), self, (self.mie_mm * factor, self.rayleigh_mm * factor))


class PopulationPrior(eqx.Module):
    """A Gaussian prior on fit variables, in their prior coordinates (``skinfit.fit``:
    log for concentrations, logit for fractions), from a calibration population.

    Attributes:
        names: the variables it covers.
        mean, sd: (n,) mean and standard deviation of each in its prior coordinate.
        noise_rms: RMS spectral residual of the population's fits: the noise scale that weighs the
            prior against a spectrum's residual.
    """

    names: tuple[str, ...] = eqx.field(static=True)
    mean: Float[Array, " n"]
    sd: Float[Array, " n"]
    noise_rms: Float[Array, ""]

    def moments(self, name: str) -> tuple[float, float]:
        """(mean, sd) of ``name`` in its prior coordinate."""
        i = self.names.index(name)
        return float(self.mean[i]), float(self.sd[i])


class SkinModel(eqx.Module):
    """Every constant of the two-layer skin model, and its forward method (see the module docstring).

    Attributes:
        epidermis_thickness_mm: epidermis thickness, mm (DJ2006: 0.25).
        blood_oxygenation: gamma, HbO2 fraction of the blood (DJ2006: 0.75).
        ior: refractive index of both layers (DJ2006: 1.4).
        epidermis_scattering, dermis_scattering: ``ScatteringLaw`` of each layer.
        baseline_scale: factor k on the bloodless-skin baseline absorption (DJ2006: 1).
        epidermal_blood: epidermal blood volume fraction as a multiple of the dermal C_h (DJ2006: 0).
        vessel_radius_mm: radius of the vessels that hold the blood, for pigment packaging (DJ2006: 0,
            blood spread evenly).
        carotene_umol_per_l: epidermal beta-carotene, umol/L (DJ2006: 0).
        surface_ior: index of the surface (oil) lobe's Fresnel factor (DJ2006 codes: 1.4).
        method: ``Diffusion()`` or ``Transport(...)``.
        prior: ``PopulationPrior`` from the calibration that made the model, or None.
        name: what output files and summaries call the model.

    Fields may be arrays that broadcast with the parameters' batch shape (e.g. a per-pixel
    oxygenation). Build variants with ``replace``: ``SkinModel.dj2006().replace(epidermis_thickness_mm=0.1)``.
    """

    epidermis_thickness_mm: Float[Array, "..."]
    blood_oxygenation: Float[Array, "..."]
    ior: Float[Array, "..."]
    epidermis_scattering: ScatteringLaw
    dermis_scattering: ScatteringLaw
    baseline_scale: Float[Array, "..."]
    epidermal_blood: Float[Array, "..."]
    vessel_radius_mm: Float[Array, "..."]
    carotene_umol_per_l: Float[Array, "..."]
    surface_ior: Float[Array, "..."]
    method: ForwardMethod
    prior: PopulationPrior | None
    name: str = eqx.field(static=True)

    def __init__(
        self,
        *,
        epidermis_thickness_mm,
        blood_oxygenation,
        ior,
        epidermis_scattering: ScatteringLaw,
        dermis_scattering: ScatteringLaw,
        baseline_scale=1.0,
        epidermal_blood=0.0,
        vessel_radius_mm=0.0,
        carotene_umol_per_l=0.0,
        surface_ior=SKIN_IOR,
        method: ForwardMethod = Diffusion(),
        prior: PopulationPrior | None = None,
        name: str = "custom",
    ):
        for field, value in (
            ("epidermis_thickness_mm", epidermis_thickness_mm),
            ("blood_oxygenation", blood_oxygenation),
            ("ior", ior),
            ("baseline_scale", baseline_scale),
            ("epidermal_blood", epidermal_blood),
            ("vessel_radius_mm", vessel_radius_mm),
            ("carotene_umol_per_l", carotene_umol_per_l),
            ("surface_ior", surface_ior),
        ):
            setattr(self, field, _field(field, value))
        if not isinstance(epidermis_scattering, ScatteringLaw) or not isinstance(dermis_scattering, ScatteringLaw):
            raise SkinfitInputError("epidermis_scattering and dermis_scattering must be skinfit.model.ScatteringLaw")
        if not isinstance(method, ForwardMethod):
            raise SkinfitInputError("method must be a forward method: skinfit.Diffusion() or skinfit.Transport(...)")
        self.epidermis_scattering, self.dermis_scattering = epidermis_scattering, dermis_scattering
        self.method, self.prior, self.name = method, prior, str(name)
        self.check()

    # -- construction -----------------------------------------------------------------------------
    @classmethod
    def dj2006(cls, method: ForwardMethod | None = None) -> "SkinModel":
        """Donner & Jensen 2006: the constants of the public DJ2006 implementations (model notes 2-4),
        on the DJ2005 multipole (or another ``method``)."""
        epidermis = ScatteringLaw(_DJ2006_MIE_MM, 0.22, _DJ2006_RAYLEIGH_MM)
        return cls(
            epidermis_thickness_mm=EPIDERMIS_THICKNESS_MM,
            blood_oxygenation=BLOOD_OXYGENATION,
            ior=SKIN_IOR,
            epidermis_scattering=epidermis,
            dermis_scattering=epidermis.scaled(0.5),
            method=Diffusion() if method is None else method,
            name="dj2006",
        )

    @classmethod
    def calibrated(cls) -> "SkinModel":
        """The model calibrated on measured skin that ships with skinfit (``spectra/calibrated_model.json``;
        how it was made: ``benchmarks/calibrate_model.py`` and docs/model.md)."""
        return _calibrated()

    @classmethod
    def default(cls) -> "SkinModel":
        """The package default: ``SkinModel.calibrated()``."""
        return _calibrated()

    @classmethod
    def named(cls, name: str) -> "SkinModel":
        """``"dj2006"``, ``"calibrated"`` (also ``"default"``), or the path of a model JSON file."""
        if name == "dj2006":
            return cls.dj2006()
        if name in ("calibrated", "default"):
            return cls.calibrated()
        if name.endswith(".json"):
            return cls.from_file(name)
        raise SkinfitInputError(f"unknown model {name!r}; choose dj2006, calibrated or a .json file written by SkinModel.save")

    def replace(self, **fields) -> "SkinModel":
        """A copy with the named fields replaced. Constants may be traced values (this works under
        jit); ``method``, ``prior`` and ``name`` rebuild the model (no tracing)."""
        unknown = [f for f in fields if f not in _FIELD_NAMES]
        if unknown:
            raise SkinfitInputError(f"unknown SkinModel field(s) {', '.join(unknown)}; fields: {', '.join(_FIELD_NAMES)}")
        structural = {f: fields.pop(f) for f in ("method", "prior", "name") if f in fields}
        model = self
        if structural:
            current = {f: getattr(self, f) for f in _FIELD_NAMES}
            model = SkinModel(**{**current, **structural})
        for field, value in fields.items():
            if field in _ARRAY_FIELDS:  # as the constructor stores it (Python floats stay weakly typed: no retrace)
                value = _field(field, value)
            model = eqx.tree_at(lambda m, f=field: getattr(m, f), model, value)
        return model

    def check(self) -> "SkinModel":
        """Raise ``SkinfitInputError`` for values outside their valid ranges (concrete values only)."""
        check_range("epidermis_thickness_mm", self.epidermis_thickness_mm, 1e-9, 1e3, unit="mm")
        check_range("blood_oxygenation", self.blood_oxygenation, 0.0, 1.0)
        check_range("ior", self.ior, 1.0, 3.0)
        check_range("surface_ior", self.surface_ior, 1.0, 3.0)
        check_range("baseline_scale", self.baseline_scale, 0.0, 1e3)
        check_range("epidermal_blood", self.epidermal_blood, 0.0, 10.0)
        check_range("vessel_radius_mm", self.vessel_radius_mm, 0.0, 1.0, unit="mm")
        check_range("carotene_umol_per_l", self.carotene_umol_per_l, 0.0, 1e5, unit="umol/L")
        for layer in ("epidermis_scattering", "dermis_scattering"):
            law = getattr(self, layer)
            check_range(f"{layer}.mie_mm", law.mie_mm, 0.0, 1e4, unit="mm^-1")
            check_range(f"{layer}.rayleigh_mm", law.rayleigh_mm, 0.0, 1e4, unit="mm^-1")
            check_range(f"{layer}.mie_power", law.mie_power, -10.0, 10.0)
            if is_concrete(law.mie_mm) and is_concrete(law.rayleigh_mm) and np.any(np.asarray(law.mie_mm) + np.asarray(law.rayleigh_mm) <= 0):
                raise SkinfitInputError(f"{layer} must scatter: mie_mm + rayleigh_mm > 0")
        self.method.check_ior(self.ior)
        return self

    # -- evaluation -------------------------------------------------------------------------------
    def layers(self, params: SkinParams, wavelengths_nm: ArrayLike, *, scattering_scale: ArrayLike = 1.0) -> tuple[Layer, Layer]:
        """Epidermis over semi-infinite dermis, fields of shape (*batch, n_wavelengths).

        ``scattering_scale`` multiplies the reduced scattering of both layers (a fit variable; 1 here).
        Computes in the floating dtype of the parameters and wavelengths.
        """
        lam = jnp.asarray(wavelengths_nm)
        dtype = jnp.result_type(lam, params.melanin, params.melanin_blend, params.haemoglobin)
        lam = lam.astype(dtype)
        model = _cast(self, dtype)
        expand = lambda x: jnp.asarray(x, dtype)[..., None]  # noqa: E731 - batch axes, then wavelength
        c_m, beta_m, c_h = expand(params.melanin), expand(params.melanin_blend), expand(params.haemoglobin)
        gamma, scale = expand(model.blood_oxygenation), expand(scattering_scale)

        base = expand(model.baseline_scale) * chrom.baseline_absorption(lam)
        melanin = beta_m * chrom.eumelanin_absorption(lam) + (1.0 - beta_m) * chrom.pheomelanin_absorption(lam)
        blood = gamma * chrom.oxyhaemoglobin_absorption(lam) + (1.0 - gamma) * chrom.deoxyhaemoglobin_absorption(lam)
        blood = blood * chrom.packaging_factor(blood, expand(model.vessel_radius_mm))
        c_he = expand(model.epidermal_blood) * c_h
        carotene = expand(model.carotene_umol_per_l) * chrom.carotene_absorption(lam)

        def law(s: ScatteringLaw):
            return scale * ScatteringLaw(expand(s.mie_mm), expand(s.mie_power), expand(s.rayleigh_mm))(lam)

        epidermis = Layer(
            absorption=c_m * melanin + c_he * blood + carotene + (1.0 - c_m - c_he) * base,
            reduced_scattering=law(model.epidermis_scattering),
            thickness=expand(model.epidermis_thickness_mm),
            ior=expand(model.ior),
        )
        dermis = Layer(
            absorption=c_h * blood + (1.0 - c_h) * base,
            reduced_scattering=law(model.dermis_scattering),
            thickness=jnp.full((), jnp.inf, dtype),
            ior=expand(model.ior),
        )
        return epidermis, dermis

    @property
    def description(self) -> str:
        """One line naming the model and its forward method (for file metadata and summaries)."""
        how = self.method.description
        if self.name == "dj2006":
            return f"dj2006: Donner & Jensen 2006 two-layer skin on {how}"
        return f"{self.name}: two-layer skin (Donner & Jensen 2006 form, skinfit constants) on {how}"

    # -- files ------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready description (scalar constants only)."""
        def scalar(x):
            arr = np.asarray(x, dtype=float)
            if arr.ndim:
                raise SkinfitInputError("only a model of scalar constants can be written to a file")
            return float(arr)

        constants = {f: scalar(getattr(self, f)) for f in _ARRAY_FIELDS}
        for layer in ("epidermis_scattering", "dermis_scattering"):
            law = getattr(self, layer)
            constants[layer] = {k: scalar(getattr(law, k)) for k in ("mie_mm", "mie_power", "rayleigh_mm")}
        out = {"name": self.name, "constants": constants, "method": self.method.to_dict()}
        if self.prior is not None:
            out["prior"] = {"names": list(self.prior.names), "mean": np.asarray(self.prior.mean).tolist(),
                            "sd": np.asarray(self.prior.sd).tolist(), "noise_rms": float(self.prior.noise_rms)}
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "SkinModel":
        """The inverse of ``to_dict`` (extra keys, such as a calibration record, are ignored)."""
        try:
            constants = dict(data["constants"])
            laws = {layer: ScatteringLaw(**constants.pop(layer)) for layer in ("epidermis_scattering", "dermis_scattering")}
            method = method_from_dict(data.get("method", {"kind": "diffusion"}), constants.get("ior", SKIN_IOR))
            prior = None
            if data.get("prior"):
                p = data["prior"]
                prior = PopulationPrior(tuple(p["names"]), jnp.asarray(p["mean"], float), jnp.asarray(p["sd"], float),
                                        jnp.asarray(p["noise_rms"], float))
            return cls(**constants, **laws, method=method, prior=prior, name=data.get("name", "custom"))
        except (KeyError, TypeError) as err:
            raise SkinfitInputError(f"not a skinfit model description: {err}") from None

    def save(self, path: str | Path, **extra) -> None:
        """Write the model as JSON (``extra`` keys are stored beside it, e.g. how it was calibrated)."""
        Path(path).write_text(json.dumps({**self.to_dict(), **extra}, indent=2) + "\n", encoding="utf-8")

    @classmethod
    def from_file(cls, path: str | Path) -> "SkinModel":
        """Read a model written by ``save``."""
        try:
            data = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            raise SkinfitInputError(f"cannot read a skinfit model from {path}: {err}") from None
        return cls.from_dict(data)


_ARRAY_FIELDS = ("epidermis_thickness_mm", "blood_oxygenation", "ior", "baseline_scale", "epidermal_blood",
                 "vessel_radius_mm", "carotene_umol_per_l", "surface_ior")
_FIELD_NAMES = (*_ARRAY_FIELDS, "epidermis_scattering", "dermis_scattering", "method", "prior", "name")

#: The shipped calibration (a resource of ``skinfit.spectra``).
CALIBRATED_MODEL_FILE = "calibrated_model.json"


@eager_cache()
def _calibrated() -> SkinModel:
    text = importlib.resources.files("skinfit.spectra").joinpath(CALIBRATED_MODEL_FILE).read_text(encoding="utf-8")
    return SkinModel.from_dict(json.loads(text))


def _cast(model: SkinModel, dtype) -> SkinModel:
    """The model's constants in ``dtype`` (the transport table keeps its own)."""
    def cast(x):
        return x.astype(dtype) if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.floating) else x

    method = model.method
    rest = eqx.tree_at(lambda m: m.method, model, None, is_leaf=lambda x: x is None)
    rest = jax.tree_util.tree_map(cast, rest)
    return eqx.tree_at(lambda m: m.method, rest, method, is_leaf=lambda x: x is None)


def cache_key(tree) -> tuple:
    """Hashable key of a pytree's structure and array values (a model, or a measurement holding one),
    for caches of what is computed per value: colour tables, fit tables, calibration kernels.

    A transport table enters through its static fields and a sample of its coefficients: they are
    built deterministically from those fields, and hashing all 4 MB of them on every fit would
    cost milliseconds."""
    is_table = lambda x: isinstance(x, TransportTable)  # noqa: E731
    tables = [t for t in jax.tree_util.tree_leaves(tree, is_leaf=is_table) if is_table(t)]
    rest = jax.tree_util.tree_map(lambda x: None if is_table(x) else x, tree, is_leaf=is_table)
    dynamic, static = eqx.partition(rest, eqx.is_array)
    leaves, treedef = jax.tree_util.tree_flatten(static)
    digest = hashlib.blake2b(digest_size=16)
    for leaf in jax.tree_util.tree_leaves(dynamic):
        digest.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    for table in tables:
        coefficients = np.asarray(table.coefficients)
        digest.update(repr((coefficients.shape, table.lower, table.step, table.anisotropy, table.ior, table.streams)).encode())
        digest.update(np.ascontiguousarray(coefficients.reshape(-1)[::101]).tobytes())
    return treedef, tuple(leaves), digest.digest()


def resolve_model(model: SkinModel | None) -> SkinModel:
    """``model`` checked, or the package default when None."""
    if model is None:
        return SkinModel.default()
    if not isinstance(model, SkinModel):
        raise SkinfitInputError(f"model must be a skinfit.SkinModel, got {type(model).__name__}")
    return model.check()


def skin_layers(params: SkinParams, wavelengths_nm: ArrayLike, *, model: SkinModel | None = None,
                scattering_scale: ArrayLike = 1.0) -> tuple[Layer, Layer]:
    """Epidermis over semi-infinite dermis for each wavelength (``SkinModel.layers``).

    Parameter arrays of batch shape (...) give layer fields of shape (..., n_wavelengths).
    """
    return resolve_model(model).layers(params, wavelengths_nm, scattering_scale=scattering_scale)
