"""Success rates as statistics: k of n with the Wilson 95% score interval (right for small n and rates near 0 or 1,
where the normal approximation's interval leaves [0, 1])."""

from __future__ import annotations

import math

Z95 = 1.959964


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a rate k/n (n > 0)."""
    if n <= 0 or not 0 <= k <= n:
        raise ValueError(f"a rate needs 0 <= k <= n and n > 0, got {k}/{n}")
    p, z2 = k / n, z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def rate(k: int, n: int) -> str:
    """'7/10 (95% CI 40-89%)', or '-' when nothing was tried."""
    if n == 0:
        return "-"
    lo, hi = wilson(k, n)
    return f"{k}/{n} (95% CI {100 * lo:.0f}-{100 * hi:.0f}%)"
