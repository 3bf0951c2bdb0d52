"""Success rates carry the Wilson 95% interval."""

import pytest

from policy_composer.app.stats import rate, wilson


@pytest.mark.parametrize("k, n, low, high", [
    (41, 50, 0.6920, 0.9023),  # the figure for the best 50-seed run: 69-90%
    (10, 10, 0.7225, 1.0),  # a perfect 10/10 still leaves 72%
    (0, 3, 0.0, 0.5615),
    (98, 100, 0.9300, 0.9945),  # the paper profile's target: lower bound 93%
])
def test_wilson_interval_matches_the_textbook_values(k, n, low, high):
    lo, hi = wilson(k, n)
    assert lo == pytest.approx(low, abs=5e-4) and hi == pytest.approx(high, abs=5e-4)


def test_a_rate_names_n_and_its_interval_and_refuses_nonsense():
    assert rate(7, 10) == "7/10 (95% CI 40-89%)" and rate(0, 0) == "-"
    with pytest.raises(ValueError, match="0 <= k <= n"):
        wilson(4, 3)
