"""Fourier signatures of 360-degree panoramas (docs/model.md §4; paper Section VI-B).

The panorama is converted to grayscale in [0, 1] and its rows are averaged
into one periodic signal s of length W. The signature is |FFT(s)[0:K]| / W.
Turning the robot on the spot shifts the panorama circularly, which changes
only the phases of the Fourier coefficients, so the magnitudes are
rotation-invariant.

    >>> panorama = np.random.default_rng(0).integers(0, 256, (32, 256, 3), dtype=np.uint8)
    >>> fourier_signature(panorama, k=5).shape
    (5,)
"""

from __future__ import annotations

import numpy as np

__all__ = ["fourier_signature", "grayscale"]

_LUMA = np.array([0.299, 0.587, 0.114])


def grayscale(panorama) -> np.ndarray:
    """An (H, W) float image in [0, 1] from an (H, W, 3) or (H, W) image, uint8 or float in [0, 1]."""
    image = np.asarray(panorama)
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ValueError(f"a panorama must have shape (H, W) or (H, W, 3), got {image.shape}")
    if image.dtype == np.uint8:
        image = image.astype(float) / 255.0
    else:
        image = image.astype(float)
        if not np.all(np.isfinite(image)):
            raise ValueError("the panorama contains non-finite values")
        if image.min() < 0.0 or image.max() > 1.0:
            raise ValueError("a float panorama must lie in [0, 1]")
    return image @ _LUMA if image.ndim == 3 else image


def fourier_signature(panorama, k: int = 5, include_dc: bool = True) -> np.ndarray:
    """The first ``k`` Fourier magnitudes of the row-averaged panorama, divided by its width.

    Parameters
    ----------
    panorama : (H, W, 3) or (H, W) array
        A 360-degree panorama; column 0 and column W-1 are neighbours.
    k : int
        Number of coefficients kept (the paper uses 5).
    include_dc : bool
        Keep the zero-frequency term (mean brightness); if False, start at frequency 1.
    """
    if int(k) != k or k < 1:
        raise ValueError(f"k must be a positive integer, got {k!r}")
    signal = grayscale(panorama).mean(axis=0)
    first = 0 if include_dc else 1
    if first + k > signal.shape[0] // 2 + 1:
        raise ValueError(f"a panorama {signal.shape[0]} pixels wide has too few frequencies for k={k}")
    spectrum = np.fft.rfft(signal)
    return np.abs(spectrum[first:first + k]) / signal.shape[0]
