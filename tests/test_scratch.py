"""Out-of-core image arrays (``skinfit._scratch``) and the image fit on them."""

from pathlib import Path

import numpy as np

from skinfit import _scratch as scratch
from skinfit.fit import fit_image
from skinfit.io import read_image, read_mask

DATA = Path(__file__).parent / "data"


def test_out_of_core_arrays_keep_their_values_after_their_pages_are_released():
    array = scratch.image_array((300, 200, 3), np.float32, on_disk=True)
    assert scratch.is_on_disk(array) and scratch.is_on_disk(array[10:20]) and scratch.is_on_disk(scratch.like(array))
    assert not scratch.is_on_disk(np.zeros(3)) and not scratch.is_on_disk(scratch.image_array((2, 2), np.uint8, on_disk=False))
    assert not array.any()  # zeroed
    values = np.random.default_rng(0).random(array.shape, np.float32)
    for rows in scratch.row_bands(300, 200, pixels=5000):  # releases after each band
        array[rows] = values[rows]
    scratch.release_pages(trim_heap=True)
    np.testing.assert_array_equal(array, values)


def test_bands_and_rows_cover_the_image_once():
    bands = list(scratch.row_bands(37, 10, pixels=64))
    assert bands[0] == slice(0, 6) and bands[-1].stop == 37
    assert np.array_equal(np.concatenate([np.arange(37)[b] for b in bands]), np.arange(37))
    image = np.arange(370.0).reshape(37, 10)
    lazy = scratch.Rows(image.shape, lambda rows: 2 * image[rows])
    assert lazy.shape == (37, 10) and np.array_equal(lazy[3:5], 2 * image[3:5])


def test_out_of_core_reading_and_fit_give_the_maps_of_the_in_memory_ones():
    """The same values, bit for bit, with the input and every map mapped from disk."""
    photo, mask = DATA / "eileen_collins_face.png", read_mask(DATA / "eileen_collins_skin_mask.png")
    in_memory, _, _ = read_image(photo, dtype=np.float32, out_of_core=False)
    on_disk, _, encoding = read_image(photo, dtype=np.float32, out_of_core=True)
    assert scratch.is_on_disk(on_disk) and not scratch.is_on_disk(in_memory)
    np.testing.assert_array_equal(on_disk, in_memory)
    expected = fit_image(photo, mask=mask, progress=False, out_of_core=False)
    found = fit_image(photo, mask=mask, progress=False, out_of_core=True)
    assert scratch.is_on_disk(found.melanin) and scratch.is_on_disk(found.fitted_linear_rgb)
    for name, value in expected.maps().items():
        np.testing.assert_array_equal(found.maps()[name], value, err_msg=name)
    np.testing.assert_array_equal(found.fitted_linear_rgb, expected.fitted_linear_rgb)
    assert found.summary()["median_dE2000"] == expected.summary()["median_dE2000"]
