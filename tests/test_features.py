"""Fourier signatures (docs/model.md §4): rotation invariance and input checks (rendered images: test_rendering)."""

import numpy as np
import pytest

from ptm.features import fourier_signature


def test_signature_is_invariant_to_circular_shifts():
    panorama = np.random.default_rng(0).integers(0, 256, size=(24, 180, 3), dtype=np.uint8)
    reference = fourier_signature(panorama, k=5)
    for shift in (1, 45, 90, 179):
        assert np.allclose(fourier_signature(np.roll(panorama, shift, axis=1), k=5), reference, atol=1e-12)


def test_signature_distinguishes_different_panoramas():
    rng = np.random.default_rng(1)
    first = rng.integers(0, 256, size=(24, 180, 3), dtype=np.uint8)
    second = rng.integers(0, 256, size=(24, 180, 3), dtype=np.uint8)
    assert not np.allclose(fourier_signature(first, k=8), fourier_signature(second, k=8), atol=1e-4)


def test_signature_of_a_pure_cosine():
    columns = np.arange(64)
    image = np.tile(0.5 + 0.25 * np.cos(2 * np.pi * 3 * columns / 64), (4, 1))
    signature = fourier_signature(image, k=5)
    assert signature == pytest.approx([0.5, 0, 0, 0.125, 0], abs=1e-12)
    assert fourier_signature(image, k=3, include_dc=False) == pytest.approx([0, 0, 0.125], abs=1e-12)


@pytest.mark.parametrize("panorama, k, message", [
    (np.zeros((4, 16, 4)), 5, "shape"),
    (np.full((4, 16), np.nan), 5, "non-finite"),
    (np.full((4, 16), 2.0), 5, r"\[0, 1\]"),
    (np.zeros((4, 6)), 5, "too few frequencies"),
    (np.zeros((4, 16)), 0, "positive integer"),
])
def test_bad_panoramas_are_refused(panorama, k, message):
    with pytest.raises(ValueError, match=message):
        fourier_signature(panorama, k=k)
