"""The station's statistical tests compare against ``scipy.special``'s quantiles: they are scipy.stats' own."""

from __future__ import annotations

import pytest
from scipy import stats

from magline.core.fit.quantiles import chi2_quantile, f_quantile, t_quantile


@pytest.mark.parametrize("probability", [0.5, 0.95, 0.99865, 1.0 - 1e-3, 1.0 - 1e-6])
@pytest.mark.parametrize("df", [1, 3, 12, 114, 5000])
def test_each_quantile_is_scipy_stats_own(probability, df):
    assert f_quantile(probability, 3, df) == pytest.approx(stats.f.ppf(probability, 3, df), rel=1e-12)
    assert f_quantile(probability, df, 400) == pytest.approx(stats.f.ppf(probability, df, 400), rel=1e-12)
    assert chi2_quantile(probability, df) == pytest.approx(stats.chi2.ppf(probability, df), rel=1e-12)
    assert t_quantile(probability, df) == pytest.approx(stats.t.ppf(probability, df), rel=1e-12, abs=1e-15)
