import os

# the suite runs without the persistent compilation cache: what it counts and times must not depend on
# what an earlier run left on disk (tests/test_compilation_cache.py checks the cache in subprocesses)
os.environ["SKINFIT_COMPILATION_CACHE"] = "0"
os.environ["SKINFIT_DISK_CACHE"] = "0"  # the tests exercise the builds (tests/test_disk_cache.py turns it on)

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import skinfit  # noqa: F401, E402 - enables float64 before any test builds arrays

#: Light-skin fixture of model notes 5.4 (C_m 0.005, beta_m 0.7, C_h 0.005) at 450, 550, 650 nm.
LIGHT_FIXTURE = {
    "wavelengths_nm": np.array([450.0, 550.0, 650.0]),
    "R1_top": np.array([0.3029, 0.2521, 0.2090]),
    "R1_bottom": np.array([0.4696, 0.4912, 0.5016]),
    "T1_top": np.array([0.3811, 0.5923, 0.7041]),
    "T1_bottom": np.array([0.2283, 0.3436, 0.3990]),
    "R2": np.array([0.4690, 0.5066, 0.7131]),
    "R12_directional": np.array([0.3553, 0.3893, 0.5209]),
    "R12_symmetric": np.array([0.3823, 0.4558, 0.6244]),
}


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_programs():
    """Drop JAX's compiled programs after each test module. One process runs the whole suite, and
    each XLA CPU executable holds memory mappings: thousands of them reach the kernel's per-process
    map limit (vm.max_map_count), where LLVM fails to allocate and the process segfaults."""
    yield
    jax.clear_caches()


@pytest.fixture
def light_fixture():
    return LIGHT_FIXTURE


@pytest.fixture
def light():
    return skinfit.preset("light")


#: Donner & Jensen 2006 (diffusion): the model of the published fixtures (model notes).
DJ2006 = skinfit.SkinModel.dj2006()


@pytest.fixture
def dj2006():
    return DJ2006
