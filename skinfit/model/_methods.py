"""Forward methods: how an epidermis over a semi-infinite dermis becomes a diffuse reflectance.

Two methods, one registry (``METHODS``, keyed by the names the command line and the keyword
``method=`` accept; strings stop at that boundary):

- ``Diffusion`` (``"diffusion"``): the DJ2005 multipole of each layer, added in the frequency domain
  (DJ2006's method);
- ``Transport``: exact 1-D radiative transport by adding-doubling with a Henyey-Greenstein phase
  function, tabulated (``"transport"``, ``Transport.tabulated``: about the cost of diffusion; the
  calibrated default model's method) or solved directly (``"transport-direct"``: the reference,
  thousands of times the cost on a CPU). A user's own stack of layers (``layered_reflectance``) is
  always solved directly: the table holds an epidermis over a semi-infinite dermis only.

Each method carries its own options and answers what the rest of the package asks of it: the
reflectance of a stack, the correction of the multipole profile's energy, how to describe and
serialise itself, and whether it is the slow direct solve.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._validate import SkinfitInputError, check_range, is_concrete
from ._adding import check_adding, stack_transfer
from ._fresnel import normal_fresnel_reflectance
from ._layers import SKIN_ANISOTROPY, SKIN_IOR, Layer
from ._transport import transport_reflectance
from ._transport_table import TransportTable, transport_table


class ForwardMethod(eqx.Module):
    """The interface of a forward method (``Diffusion``, ``Transport``)."""

    name: ClassVar[str]

    @property
    def profile_adding(self) -> str:
        """The layer adding the multipole profile's shape uses with this method."""
        return "directional"

    @property
    def solves_directly(self) -> bool:
        """True for the direct adding-doubling solve (callers then use smaller batches, fewer nodes)."""
        return False

    def reflectance(self, epidermis: Layer, dermis: Layer):
        """(1 - F0) R12(0) of ``epidermis`` over a semi-infinite ``dermis`` (arrays of their broadcast shape)."""
        raise NotImplementedError

    def energy_correction(self, epidermis: Layer, dermis: Layer):
        """The factor that scales the multipole profile to this method's total reflectance."""
        raise NotImplementedError

    def check_ior(self, ior) -> None:
        """A clear error where the method cannot serve a model of this refractive index."""

    @property
    def description(self) -> str:
        raise NotImplementedError

    def to_dict(self) -> dict:
        raise NotImplementedError

    @classmethod
    def stack_reflectance(cls, layers: Sequence[Layer], *, adding: str, ior_above, ior_below, streams: int):
        """(1 - F0) R12(0) of a user stack of layers (top first, each with its own g)."""
        raise NotImplementedError


class Diffusion(ForwardMethod):
    """Forward method: DJ2005 multipole layers added in the frequency domain (model notes 5).

    ``adding``: ``"directional"`` (default) or ``"symmetric"`` (DJ2005-literal, for comparison).
    """

    adding: str = eqx.field(static=True, default="directional")
    name: ClassVar[str] = "diffusion"

    def __check_init__(self):
        check_adding(self.adding)

    @property
    def profile_adding(self) -> str:
        return self.adding

    def reflectance(self, epidermis: Layer, dermis: Layer):
        r12 = stack_transfer([epidermis, dermis], 0.0, adding=self.adding)
        return (1.0 - normal_fresnel_reflectance(epidermis.ior)) * r12

    def energy_correction(self, epidermis: Layer, dermis: Layer):
        return jnp.ones_like(jnp.asarray(epidermis.absorption))

    @property
    def description(self) -> str:
        return "the closed-form DJ2005 multipole" + ("" if self.adding == "directional" else f" ({self.adding} adding)")

    def to_dict(self) -> dict:
        return {"kind": self.name, "adding": self.adding}

    @classmethod
    def from_dict(cls, spec: dict, ior: float) -> "Diffusion":
        return cls(spec.get("adding", "directional"))

    @classmethod
    def from_options(cls, *, adding=None, anisotropy=None, ior=None, streams=None) -> "Diffusion":
        return cls(adding or "directional")

    @classmethod
    def stack_reflectance(cls, layers, *, adding, ior_above, ior_below, streams):
        return _diffusion_stack_reflectance(layers, adding, jnp.asarray(ior_above), jnp.asarray(ior_below))


class Transport(ForwardMethod):
    """Forward method: exact 1-D radiative transport (adding-doubling) with Henyey-Greenstein g.

    With a ``table`` (``Transport.tabulated``), the epidermis-over-dermis reflectance comes from the
    tabulated adding-doubling (about the cost of diffusion); without one it is solved directly
    (thousands of times the cost on a CPU; the reference).
    """

    anisotropy: float = eqx.field(static=True, default=SKIN_ANISOTROPY)
    ior: float = eqx.field(static=True, default=SKIN_IOR)
    streams: int = eqx.field(static=True, default=16)
    table: TransportTable | None = None
    name: ClassVar[str] = "transport"

    @classmethod
    def tabulated(cls, anisotropy: float = SKIN_ANISOTROPY, ior: float = SKIN_IOR, streams: int = 16) -> "Transport":
        """Transport through the table for this g and index (shipped, cached or built once)."""
        table = transport_table(float(anisotropy), float(ior), streams=int(streams))
        return cls(float(anisotropy), float(ior), int(streams), table)

    @property
    def solves_directly(self) -> bool:
        return self.table is None

    def reflectance(self, epidermis: Layer, dermis: Layer):
        if self.table is not None:
            return self.table.reflectance(epidermis.absorption, epidermis.reduced_scattering, epidermis.thickness,
                                          dermis.absorption, dermis.reduced_scattering)
        shape = jnp.broadcast_shapes(jnp.shape(epidermis.absorption), jnp.shape(dermis.absorption))
        g = jnp.full(shape, self.anisotropy, jnp.result_type(epidermis.absorption))
        layers = [eqx.tree_at(lambda layer: layer.anisotropy, layer, g) for layer in (epidermis, dermis)]
        return transport_reflectance(layers, streams=self.streams, ior=self.ior, semi_infinite=True)

    def check_ior(self, ior) -> None:
        if is_concrete(ior):
            values = np.unique(np.asarray(ior, dtype=float))
            if values.size != 1 or abs(float(values[0]) - self.ior) > 1e-9:
                raise SkinfitInputError(f"the transport method is for ior {self.ior} (static); the model's ior is "
                                        f"{', '.join(f'{v:g}' for v in values)}: build Transport with the model's index")

    def energy_correction(self, epidermis: Layer, dermis: Layer):
        # the multipole gives the profile's shape; transport its total
        return self.reflectance(epidermis, dermis) / Diffusion().reflectance(epidermis, dermis)

    @property
    def description(self) -> str:
        return (f"exact 1-D transport ({'tabulated ' if self.table is not None else ''}adding-doubling, "
                f"Henyey-Greenstein g {self.anisotropy:g}, n {self.ior:g})")

    def to_dict(self) -> dict:
        return {"kind": self.name, "anisotropy": self.anisotropy, "ior": self.ior, "streams": self.streams,
                "tabulated": self.table is not None}

    @classmethod
    def from_dict(cls, spec: dict, ior: float) -> "Transport":
        g, streams = spec.get("anisotropy", SKIN_ANISOTROPY), spec.get("streams", 16)
        if spec.get("tabulated", True):
            return cls.tabulated(g, ior, streams)
        return cls(float(g), float(ior), int(streams))

    @classmethod
    def from_options(cls, *, adding=None, anisotropy=None, ior=None, streams=None, tabulated: bool = True) -> "Transport":
        """Transport for one concrete index: through the table (``method="transport"``; shipped for
        g 0.8 and n 1.4, built once and cached on disk for other values) or the direct solve
        (``method="transport-direct"``, the reference)."""
        ior_values = np.unique(np.asarray(ior, dtype=float)) if ior is not None and is_concrete(ior) else None
        if ior_values is None or ior_values.size != 1:
            raise SkinfitInputError("method='transport' needs one concrete ior for the skin")
        g = SKIN_ANISOTROPY if anisotropy is None else anisotropy
        check_range("anisotropy", g, -0.99, 0.99)
        if np.ndim(g) != 0:
            raise SkinfitInputError("anisotropy must be one value")
        if tabulated:
            return cls.tabulated(float(g), float(ior_values[0]), int(streams or 16))
        return cls(float(g), float(ior_values[0]), int(streams or 16))

    @classmethod
    def stack_reflectance(cls, layers, *, adding, ior_above, ior_below, streams):
        # one index for the whole stack; a finite bottom layer exits into a medium of its own index
        check_range("ior_above", ior_above, 1.0, 3.0)
        return transport_reflectance(layers, ior_above=float(np.asarray(ior_above)), streams=streams)


@eqx.filter_jit
def _diffusion_stack_reflectance(layers, adding, ior_above, ior_below):
    r12 = stack_transfer(layers, 0.0, adding=adding, ior_above=ior_above, ior_below=ior_below)
    return (1.0 - normal_fresnel_reflectance(layers[0].ior, ior_above)) * r12


#: The forward methods by the names the ``method=`` keyword and ``--method`` accept: each name's
#: method class and the options the name implies.
METHODS: dict[str, tuple[type[ForwardMethod], dict]] = {
    "diffusion": (Diffusion, {}),
    "transport": (Transport, {"tabulated": True}),
    "transport-direct": (Transport, {"tabulated": False}),
}


def method_class(name: str) -> type[ForwardMethod]:
    """The method class registered as ``name``; a clear error for any other string."""
    if not isinstance(name, str) or name not in METHODS:
        raise SkinfitInputError(f"method must be one of {', '.join(METHODS)}, got {name!r}")
    return METHODS[name][0]


def method_from_options(name: str, *, adding=None, anisotropy=None, ior=None, streams=None) -> ForwardMethod:
    """The method ``name`` (a ``method=`` keyword) with the public functions' keyword options."""
    cls = method_class(name)
    return cls.from_options(adding=adding, anisotropy=anisotropy, ior=ior, streams=streams, **METHODS[name][1])


def method_from_dict(spec: dict, ior: float) -> ForwardMethod:
    """The method a model file describes (``{"kind": name, ...options}``)."""
    return method_class(spec.get("kind", "diffusion")).from_dict(spec, ior)
