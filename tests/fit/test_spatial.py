"""Image-space helpers: smooth fields from scattered pixels, edge-preserving neighbourhood values."""

import numpy as np

from skinfit.fit import neighbourhood_median, smooth_field, speckle_fraction


def test_smooth_field_fills_holes_with_the_surroundings():
    y, x = np.mgrid[0:120, 0:90]
    values = 0.01 * x + 0.02 * y  # a plane: any normalised smoothing keeps it inside
    weights = (np.random.default_rng(0).random(values.shape) > 0.7).astype(float)
    weights[40:60, 30:50] = 0.0  # a hole
    field = smooth_field(np.where(weights > 0, values, 99.0), weights, sigma_px=4.0)
    inner = np.zeros(values.shape, bool)
    inner[12:-12, 12:-12] = True
    near_hole = np.zeros(values.shape, bool)
    near_hole[34:66, 24:56] = True  # the hole and 1.5 sigma around it
    np.testing.assert_allclose(field[inner & ~near_hole], values[inner & ~near_hole], atol=0.03)
    hole = np.zeros(values.shape, bool)
    hole[40:60, 30:50] = True
    # inside the hole: a weighted mean of its surroundings (never the 99 that stands in the holes)
    ring = values[36:64, 26:54]
    assert ring.min() <= field[hole].min() and field[hole].max() <= ring.max()
    assert np.all(np.isfinite(field))


def test_smooth_field_without_weights_is_zero_not_nan():
    assert np.all(smooth_field(np.ones((8, 8)), np.zeros((8, 8)), 2.0) == 0.0)


def test_neighbourhood_median_keeps_an_edge_and_removes_a_speck():
    values = np.where(np.arange(40)[None, :] < 20, 0.02, 0.2) * np.ones((30, 1))
    values[10, 5] = 0.5  # an isolated pixel on the other branch
    valid = np.ones_like(values, bool)
    median = neighbourhood_median(values, valid, 3, values)
    assert median[10, 5] == 0.02
    np.testing.assert_array_equal(median[:, 18:22], values[:, 18:22])  # the step stays where it is


def test_speckle_fraction_counts_isolated_pixels():
    values = np.full((50, 50), 0.05)
    valid = np.ones_like(values, bool)
    assert speckle_fraction(values, valid) == 0.0
    values[[5, 20, 30], [5, 20, 30]] = 0.3
    assert np.isclose(speckle_fraction(values, valid), 3 / 2500)


def test_smooth_field_interpolates_back_in_bands_to_the_whole_images_values(monkeypatch):
    """The field is interpolated back to the image a band of rows at a time (bounded temporaries):
    on an image of several bands the values are those of one interpolation over the whole image."""
    from skinfit.fit import _spatial

    rng = np.random.default_rng(1)
    values, weights = rng.normal(size=(700, 300)), (rng.random((700, 300)) > 0.5).astype(float)
    tables = []  # the coarse field (blocks of 4 pixels at sigma 9) goes first to the interpolation
    interpolate = _spatial._interpolate_axis0
    monkeypatch.setattr(_spatial, "_interpolate_axis0", lambda table, at: tables.append(table) or interpolate(table, at))
    field = smooth_field(values, weights, sigma_px=9.0)
    along_rows = interpolate(tables[0], (np.arange(700) + 0.5) / 4 - 0.5)
    whole = interpolate(along_rows.T, (np.arange(300) + 0.5) / 4 - 0.5).T.astype(np.float32)
    assert field.dtype == np.float32 and len(tables) > 2  # several bands
    np.testing.assert_array_equal(field, whole)
