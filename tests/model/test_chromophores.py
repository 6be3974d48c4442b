import numpy as np
import pytest

from skinfit import model as chrom

# model notes 2.1 check values (mm^-1)
SPOT = {
    # wavelength: (eumelanin, pheomelanin, baseline, oxy, deoxy, sigma_s' epidermis), as printed
    450: ("96.46", "72.38", "0.1219", "33.643", "55.321", "9.209"),
    500: ("67.92", "43.88", "0.0702", "11.211", "11.173", "7.276"),
    550: ("49.45", "27.91", "0.0459", "23.039", "28.607", "6.082"),
    600: ("37.01", "18.46", "0.0345", "1.714", "7.861", "5.306"),
    650: ("28.35", "12.62", "0.0292", "0.197", "2.009", "4.778"),
    700: ("22.15", "8.875", "0.0266", "0.155", "0.961", "4.404"),
}
FUNCTIONS = (
    chrom.eumelanin_absorption,
    chrom.pheomelanin_absorption,
    chrom.baseline_absorption,
    chrom.oxyhaemoglobin_absorption,
    chrom.deoxyhaemoglobin_absorption,
    chrom.epidermis_reduced_scattering,
)


@pytest.mark.parametrize("wavelength", sorted(SPOT))
def test_spot_values_match_model_table(wavelength):
    for func, printed in zip(FUNCTIONS, SPOT[wavelength]):
        value = float(func(float(wavelength)))
        # model notes rounds some intermediate values: allow one unit in the last printed digit
        last_digit = 10.0 ** -len(printed.split(".")[1])
        assert abs(value - float(printed)) <= last_digit, func.__name__


def test_prahl_table_spot_values_and_conversion():
    wl, oxy, deoxy = chrom.haemoglobin_table()
    assert wl[0] == 250 and wl[-1] == 1000 and np.all(np.diff(wl) == 2)
    table = dict(zip(wl, zip(oxy, deoxy)))
    assert table[414] == (524280, 342596)
    assert table[650] == (368, 3750.12)
    # 414 nm in mm^-1, as hard-coded by damlaren (model notes 2.1)
    assert float(chrom.oxyhaemoglobin_absorption(414.0)) == pytest.approx(280.795, rel=1e-5)
    assert float(chrom.deoxyhaemoglobin_absorption(414.0)) == pytest.approx(183.488, rel=1e-5)


def test_dermis_scatters_half_the_epidermis():
    lam = np.linspace(300, 1000, 15)
    np.testing.assert_allclose(chrom.dermis_reduced_scattering(lam), 0.5 * chrom.epidermis_reduced_scattering(lam))


def test_haemoglobin_table_is_shipped_with_its_citation():
    import importlib.resources

    text = importlib.resources.files("skinfit.spectra").joinpath("prahl_haemoglobin.csv").read_text()
    header = "\n".join(line for line in text.splitlines() if line.startswith("#"))
    assert "Prahl" in header and "Gratzer" in header and "Kollias" in header and "cm^-1" in header
