"""The shipped TFLite models and the interpreter that runs them (``ai-edge-litert``)."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np

MODEL_DIR = Path(__file__).parent / "models"

#: One interpreter per model and thread (a TFLite interpreter is not thread-safe).
_LOCAL = threading.local()


class SegmentationUnavailable(RuntimeError):
    """The TFLite runtime cannot be imported on this platform."""


def available() -> bool:
    """Whether ``ai-edge-litert`` imports here (wheels exist for x86-64 Linux, macOS arm64, Windows)."""
    try:
        _interpreter_class()
    except SegmentationUnavailable:
        return False
    return True


def _interpreter_class():
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError as error:  # an optional platform: fall back to the model-gamut rule
        raise SegmentationUnavailable(f"face segmentation needs ai-edge-litert ({error})") from error
    return Interpreter


def run_model(name: str, x: np.ndarray) -> list[np.ndarray]:
    """Outputs of model ``name`` (a file in ``MODEL_DIR``) on one input ``x`` (no batch axis)."""
    cache = _LOCAL.__dict__.setdefault("interpreters", {})
    if name not in cache:
        interpreter = _interpreter_class()(model_path=str(MODEL_DIR / name), num_threads=os.cpu_count() or 1)
        interpreter.allocate_tensors()
        cache[name] = interpreter
    interpreter = cache[name]
    interpreter.set_tensor(interpreter.get_input_details()[0]["index"], np.ascontiguousarray(x[None], np.float32))
    interpreter.invoke()
    return [interpreter.get_tensor(d["index"]) for d in interpreter.get_output_details()]
