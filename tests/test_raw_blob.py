"""Raw samples are stored as a compact .npy float32 array: lossless to the sensor's resolution,
readable by plain NumPy, and shown as the sensor's own numbers when exported."""

from __future__ import annotations

import io

import numpy as np
import pytest

from magline.core.fit.samples_csv import RawSamples, format_samples
from magline.core.results import raw_blob


def samples(n: int = 600, applied: bool = False) -> RawSamples:
    rng = np.random.default_rng(7)
    mag = np.round(rng.normal(scale=60.0, size=(n, 3)) + np.array([120.0, -40.0, 30.0]), 1)  # 0.1 µT steps (mG ints)
    return RawSamples(mag_ut=mag, t_ms=np.cumsum(rng.uniform(15, 25, n)), temp_c=25 + rng.normal(scale=0.2, size=n),
                      applied_ut=rng.normal(scale=50.0, size=(n, 3)) if applied else None)


@pytest.mark.parametrize("applied", [False, True])
def test_round_trip_keeps_every_column_to_the_sensors_resolution(applied):
    original = samples(applied=applied)
    back = raw_blob.decode(raw_blob.encode(original))
    assert back.mag_ut.tolist() == original.mag_ut.tolist()  # 0.1 µT values come back as written
    np.testing.assert_array_equal(back.t_ms, original.t_ms)  # time is float64: exact
    np.testing.assert_allclose(back.temp_c, original.temp_c, atol=1e-5)
    if applied:
        np.testing.assert_allclose(back.applied_ut, original.applied_ut, rtol=1e-6, atol=1e-5)
    else:
        assert back.applied_ut is None


def test_a_blob_is_a_plain_npy_array_named_like_the_csv_and_smaller_than_it():
    original = samples()
    blob = raw_blob.encode(original)
    table = np.load(io.BytesIO(blob), allow_pickle=False)  # no magline needed to read it
    assert table.dtype.names == ("mag_x_ut", "mag_y_ut", "mag_z_ut", "t_ms", "temp_c")
    assert len(blob) < 0.7 * len(format_samples(original).encode())
    assert len(blob) < 24 * 600 + 256  # 3×4 + 8 + 4 bytes a sample, plus the header


def test_what_is_not_a_raw_array_is_refused_with_words():
    with pytest.raises(raw_blob.RawBlobError, match=r"no \.npy header"):
        raw_blob.decode(b"mag_x_ut,mag_y_ut\n1,2\n")
    out = io.BytesIO()
    np.save(out, np.zeros(3, dtype=[("x", "<f4")]))
    with pytest.raises(raw_blob.RawBlobError, match="mag_x_ut, mag_y_ut, mag_z_ut"):
        raw_blob.decode(out.getvalue())
