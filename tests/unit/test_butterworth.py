"""The rtklibexplorer loader's zero-phase low-pass (zennav.datasets.butterworth): scipy's coefficients and scipy's
filtfilt floats, bit for bit, without importing scipy.signal."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, filtfilt

from zennav.datasets.butterworth import COEFFICIENTS, PAD, lowpass


@pytest.mark.parametrize("wn", sorted(COEFFICIENTS))
def test_coefficients_are_scipy_butter(wn):
    b, a = butter(4, wn)
    assert COEFFICIENTS[wn] == (tuple(b.tolist()), tuple(a.tolist()))


@pytest.mark.parametrize("wn", sorted(COEFFICIENTS))
@pytest.mark.parametrize("n", [PAD + 1, 40, 5_000])
def test_lowpass_is_scipy_filtfilt_bit_for_bit(wn, n):
    rng = np.random.default_rng(n)
    x = rng.standard_normal((n, 3)) * [1.0, 1e-3, 50.0] + np.linspace(0.0, 3.0, n)[:, None]  # noise on a ramp
    want = filtfilt(*butter(4, wn), x, axis=0)
    got = lowpass(x, wn)
    assert got.shape == x.shape and np.array_equal(got, want)
    assert np.array_equal(lowpass(x[:, 1], wn), filtfilt(*butter(4, wn), x[:, 1]))  # one column, 1-D


def test_lowpass_refuses_what_it_cannot_filter():
    with pytest.raises(ValueError, match="more than 15 samples"):
        lowpass(np.zeros(PAD), 0.2)
    with pytest.raises(ValueError, match="wn=0.3"):
        lowpass(np.zeros(100), 0.3)
