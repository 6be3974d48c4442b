"""The planner: from a ``Request`` (what outputs, at which scale) to the smallest computation
(``Plan``), and its evaluation.
"""

from ._planner import (
    DERIVATIVE_NAMES,
    Plan,
    Request,
    _program,
    evaluate,
    plan,
    rgb_wavelengths,
)

__all__ = [
    "_program",
    "DERIVATIVE_NAMES",
    "evaluate",
    "Plan",
    "plan",
    "Request",
    "rgb_wavelengths",
]
