"""The skin model, lowest stage of the data flow: parameters -> optical coefficients -> layer
responses -> adding -> reflectance and radial profiles.

Chromophore spectra and parameters (``SkinParams``, presets), the model object (``SkinModel`` with its
method, ``Diffusion`` or ``Transport``), layer optics, Fresnel, the multipole (DJ2005), adding, the Hankel
quadrature, radial profiles, exact transport (adding-doubling and its table), the surface (oil) layer and
the Monte Carlo reference. Imports nothing from the other stages.
"""

from ._adding import ADDING_MODES, add_below, stack_reflectance, stack_transfer
from ._chromophores import (
    WAVELENGTH_RANGE_NM,
    baseline_absorption,
    carotene_absorption,
    deoxyhaemoglobin_absorption,
    dermis_reduced_scattering,
    epidermis_reduced_scattering,
    eumelanin_absorption,
    haemoglobin_table,
    oxyhaemoglobin_absorption,
    packaging_factor,
    pheomelanin_absorption,
)
from ._fresnel import fresnel_reflectance, normal_fresnel_reflectance
from ._hankel import HankelQuadrature, energy_kernel, inverse_kernel
from ._layers import SKIN_ANISOTROPY, SKIN_IOR, Layer
from ._methods import METHODS, Diffusion, ForwardMethod, Transport
from ._monte_carlo import MonteCarloResult, monte_carlo_reflectance
from ._multipole import (
    SlabResponse,
    boundary_coefficient,
    dipole_energy,
    dipole_profile,
    dipole_transfer,
    fresnel_diffuse_reflectance,
    slab_response,
)
from ._params import PRESET_NAMES, SkinParams, preset, preset_source
from ._profiles import (
    captured_of_layers,
    captured_reflectance,
    layered_profile,
    profile,
    skin_profile,
)
from ._reflectance import (
    diffuse_reflectance,
    layered_reflectance,
    model_with_options,
    skin_reflectance,
    skin_stack_reflectance,
)
from ._skin_model import (
    PopulationPrior,
    ScatteringLaw,
    SkinModel,
    cache_key,
    resolve_model,
    skin_layers,
)
from ._surface import (
    SURFACE_IOR,
    SURFACE_ROUGHNESS,
    _unit_lobe,
    brdf,
    fresnel_dielectric,
    lobe_albedo,
    reflectance_factor,
    surface_energy,
)
from ._transport import solve_dominant, stack_reflectance_transport
from ._transport_table import (
    DEFAULT_NODES,
    RATIO_RANGE,
    THICKNESS_RANGE,
    build_transport_table,
    grid_axes,
    load_table,
    node_reflectance,
    saturation_thickness,
    save_table,
    transport_table,
)

__all__ = [
    "WAVELENGTH_RANGE_NM",
    "_unit_lobe",
    "add_below",
    "ADDING_MODES",
    "baseline_absorption",
    "boundary_coefficient",
    "brdf",
    "build_transport_table",
    "cache_key",
    "captured_of_layers",
    "captured_reflectance",
    "carotene_absorption",
    "DEFAULT_NODES",
    "deoxyhaemoglobin_absorption",
    "dermis_reduced_scattering",
    "diffuse_reflectance",
    "Diffusion",
    "dipole_energy",
    "dipole_profile",
    "dipole_transfer",
    "energy_kernel",
    "epidermis_reduced_scattering",
    "eumelanin_absorption",
    "ForwardMethod",
    "fresnel_dielectric",
    "fresnel_diffuse_reflectance",
    "grid_axes",
    "haemoglobin_table",
    "fresnel_reflectance",
    "HankelQuadrature",
    "inverse_kernel",
    "Layer",
    "layered_profile",
    "layered_reflectance",
    "load_table",
    "lobe_albedo",
    "METHODS",
    "model_with_options",
    "monte_carlo_reflectance",
    "MonteCarloResult",
    "node_reflectance",
    "normal_fresnel_reflectance",
    "oxyhaemoglobin_absorption",
    "packaging_factor",
    "pheomelanin_absorption",
    "PopulationPrior",
    "preset",
    "PRESET_NAMES",
    "preset_source",
    "profile",
    "RATIO_RANGE",
    "reflectance_factor",
    "resolve_model",
    "saturation_thickness",
    "save_table",
    "ScatteringLaw",
    "SKIN_ANISOTROPY",
    "SKIN_IOR",
    "skin_layers",
    "skin_profile",
    "skin_reflectance",
    "skin_stack_reflectance",
    "SkinModel",
    "SkinParams",
    "slab_response",
    "SlabResponse",
    "solve_dominant",
    "stack_reflectance",
    "stack_reflectance_transport",
    "stack_transfer",
    "surface_energy",
    "SURFACE_IOR",
    "SURFACE_ROUGHNESS",
    "THICKNESS_RANGE",
    "Transport",
    "transport_table",
]
