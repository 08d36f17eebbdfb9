# SPDX-License-Identifier: Apache-2.0
"""Confidence bounds on a rate measured by counting: k events in n independent trials."""
from __future__ import annotations

from scipy.stats import beta


def rate_upper_bound(events: int, trials: int, confidence: float = 0.95) -> float:
    """
    Return the one-sided upper confidence bound on a rate from `events` in `trials` (Clopper-Pearson).

    Exact for a binomial count: with no event, 1 - (1 - confidence)^(1/trials) (~3/n at 95 %).
    """
    if trials <= 0 or not 0 <= events <= trials:
        raise ValueError(f"need 0 <= events ({events}) <= trials ({trials}) and trials > 0")
    if events == trials:
        return 1.0
    return float(beta.ppf(confidence, events + 1, trials - events))
