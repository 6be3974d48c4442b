"""The import paths of skinfit 0.1 (32 flat modules, 58 top-level names), kept working for one release.

``import skinfit.reflectance``, ``from skinfit.multipole import slab_response`` and
``skinfit.stack_reflectance`` still work and emit a ``DeprecationWarning`` that names the new home
(``skinfit.model`` and friends); they will be removed in skinfit 0.3.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types
import warnings

# old module name -> the module that now holds its code (its public names are re-exported by the
# subpackage, which is where new code should import them from)
MOVED_MODULES = {
    "adding": "skinfit.model._adding",
    "calibration": "skinfit.fit._image_calibration",
    "chromophores": "skinfit.model._chromophores",
    "colour_chart": "skinfit.colorimetry._colour_chart",
    "colour_table": "skinfit.colorimetry._colour_table",
    "distributed": "skinfit.cli._dask",
    "fit_outputs": "skinfit.cli._batch",
    "fit_table": "skinfit.fit._warm_start",
    "fit_variables": "skinfit.fit._variables",
    "fresnel": "skinfit.model._fresnel",
    "hankel": "skinfit.model._hankel",
    "image_fit": "skinfit.fit._images",
    "images": "skinfit.io._images",
    "layers": "skinfit.model._layers",
    "map_rendering": "skinfit.colorimetry._map_rendering",
    "measurements": "skinfit.io._measurements",
    "mitsuba": "skinfit.export._mitsuba",
    "model_calibration": "skinfit.fit._model_calibration",
    "monte_carlo": "skinfit.model._monte_carlo",
    "multipole": "skinfit.model._multipole",
    "params": "skinfit.model._params",
    "pixel_fit": "skinfit.fit._pixels",
    "planning": "skinfit.planning._planner",
    "plots": "skinfit.cli._plots",
    "profiles": "skinfit.model._profiles",
    "reflectance": "skinfit.model._reflectance",
    "renderer_media": "skinfit.export._media",
    "renderers": "skinfit.export._renderers",
    "skin_model": "skinfit.model._skin_model",
    "spectral_fit": "skinfit.fit._spectra",
    "surface": "skinfit.model._surface",
    "tables": "skinfit.export._profile_tables",
    "transport": "skinfit.model._transport",
    "transport_fit": "skinfit.fit._transport_polish",
    "transport_table": "skinfit.model._transport_table",
}

# old top-level name -> the subpackage that exports it now
MOVED_NAMES = {
    "chart_calibration": "skinfit.colorimetry",
    "ChartCalibration": "skinfit.colorimetry",
    "colour_table": "skinfit.colorimetry",
    "ColourTable": "skinfit.colorimetry",
    "linear_srgb_weights": "skinfit.colorimetry",
    "spectrum_to_linear_srgb": "skinfit.colorimetry",
    "spectrum_to_xyz": "skinfit.colorimetry",
    "srgb_decode": "skinfit.colorimetry",
    "srgb_encode": "skinfit.colorimetry",
    "xyz_to_linear_srgb": "skinfit.colorimetry",
    "xyz_weights": "skinfit.colorimetry",
    "ProfileTable": "skinfit.export",
    "read_exr_table": "skinfit.export",
    "renderer_textures": "skinfit.export",
    "RendererConventions": "skinfit.export",
    "RendererMedium": "skinfit.export",
    "RendererProfiles": "skinfit.export",
    "transport_medium": "skinfit.export",
    "write_table": "skinfit.export",
    "calibrate": "skinfit.fit",
    "fit_pixels": "skinfit.fit",
    "ImageCalibration": "skinfit.fit",
    "SolverSettings": "skinfit.fit",
    "ArchiveSpectra": "skinfit.io",
    "NistSpectra": "skinfit.io",
    "read_linear_rgb": "skinfit.io",
    "read_mask": "skinfit.io",
    "brdf": "skinfit.model",
    "captured_reflectance": "skinfit.model",
    "HankelQuadrature": "skinfit.model",
    "layered_profile": "skinfit.model",
    "lobe_albedo": "skinfit.model",
    "monte_carlo_reflectance": "skinfit.model",
    "MonteCarloResult": "skinfit.model",
    "PopulationPrior": "skinfit.model",
    "preset_source": "skinfit.model",
    "reflectance_factor": "skinfit.model",
    "ScatteringLaw": "skinfit.model",
    "skin_layers": "skinfit.model",
    "slab_response": "skinfit.model",
    "SlabResponse": "skinfit.model",
    "stack_reflectance": "skinfit.model",
    "stack_transfer": "skinfit.model",
    "surface_energy": "skinfit.model",
    "Plan": "skinfit.planning",
}


def _warn(old: str, new: str, stacklevel: int) -> None:
    warnings.warn(f"{old} is deprecated (removed in skinfit 0.3); use {new}", DeprecationWarning, stacklevel=stacklevel)


def _subpackage(module_path: str) -> str:
    return module_path.rsplit(".", 1)[0]


class _MovedModule(types.ModuleType):
    """Stands in for an old flat module: every attribute is read from the module that holds the code now."""

    def __init__(self, name: str, target: str):
        super().__init__(name, f"Deprecated alias of {target}.")
        self.__dict__["_target"] = target

    def __getattr__(self, attribute: str):
        return getattr(importlib.import_module(self.__dict__["_target"]), attribute)

    def __dir__(self):
        return dir(importlib.import_module(self.__dict__["_target"]))


class _MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves ``import skinfit.<old module>`` to a ``_MovedModule`` (with the warning)."""

    def find_spec(self, fullname, path=None, target=None):
        package, _, name = fullname.partition(".")
        if package == "skinfit" and name in MOVED_MODULES:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        target = MOVED_MODULES[spec.name.partition(".")[2]]
        _warn(spec.name, _subpackage(target), stacklevel=3)
        return _MovedModule(spec.name, target)

    def exec_module(self, module) -> None:
        pass


def install_finder() -> None:
    if not any(isinstance(finder, _MovedModuleFinder) for finder in sys.meta_path):
        sys.meta_path.append(_MovedModuleFinder())


def moved_attribute(name: str):
    """``skinfit.<name>`` for an old top-level name or module; AttributeError for anything else."""
    if name in MOVED_NAMES:
        _warn(f"skinfit.{name}", f"{MOVED_NAMES[name]}.{name}", stacklevel=4)  # the caller of skinfit.__getattr__
        return getattr(importlib.import_module(MOVED_NAMES[name]), name)
    if name in MOVED_MODULES:
        return importlib.import_module(f"skinfit.{name}")
    raise AttributeError(f"module 'skinfit' has no attribute {name!r}")
