from pathlib import Path

import numpy as np
import pytest

import skinfit
from skinfit.io import read_nist

DATA = Path(__file__).resolve().parents[2] / "data"


def test_bundled_nist_subset_reads_with_the_values_its_readme_states():
    nist = read_nist(DATA / "nist_skin_reflectance_250-1000nm.csv")
    assert nist.average.shape == (100, 251) and nist.repeats.shape == (100, 3, 251)
    assert nist.wavelengths_nm[0] == 250 and nist.wavelengths_nm[-1] == 1000
    at_550 = nist.average[:, int(np.argmin(np.abs(nist.wavelengths_nm - 550)))]
    # the NIST data's README (shared/data/nist-skin-reflectance): subject averages at 550 nm span 0.114 to 0.416
    assert at_550.min() == pytest.approx(0.114, abs=6e-4) and at_550.max() == pytest.approx(0.416, abs=6e-4)
    # the published average is the mean of the repeats, to the 4 printed decimals
    assert np.max(np.abs(nist.repeats.mean(axis=1) - nist.average)) < 1e-4


def test_not_nist_layout_is_a_clear_error(tmp_path):
    path = tmp_path / "x.csv"
    path.write_text("a,b\n1,2\n")
    with pytest.raises(skinfit.SkinfitInputError, match="NIST layout"):
        read_nist(path)
    with pytest.raises(skinfit.SkinfitInputError, match="cannot read"):
        read_nist(tmp_path / "missing.csv")
