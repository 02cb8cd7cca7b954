"""Interval estimates for success rates and for paired differences between methods.

Plain Python on purpose: three closed-form formulas do not justify a scipy import in a command
that only reads a database. Why these estimators is explained in docs/reports.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

Z95 = 1.959963984540054  # standard normal 97.5% quantile


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion, as fractions in [0, 1].

    Unlike the normal (Wald) interval it stays inside [0, 1] and keeps a sensible width at 0/n and
    n/n, which are common here (many tasks succeed in every or no trial). ``n == 0`` gives NaNs.
    """
    if n < 0 or successes < 0 or successes > n:
        raise ValueError(f"need 0 <= successes <= n, got {successes}/{n}")
    if n == 0:
        return (math.nan, math.nan)
    p = successes / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    # At 0/n and n/n the bound is exactly the end: computed, it can land a rounding error inside
    # [0, 1] (1e-17 above 0), which puts the interval just beside the estimate it must contain.
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return (lo, hi)


def mcnemar_exact(only_a: int, only_b: int) -> float:
    """Two-sided exact McNemar p-value: a binomial(only_a + only_b, 1/2) test on the discordant
    pairs. Exact because with tens of trials the chi-square approximation is poor."""
    m = only_a + only_b
    if m == 0:
        return 1.0
    k = min(only_a, only_b)
    tail = sum(math.comb(m, i) for i in range(k + 1)) / 2 ** m
    return min(1.0, 2 * tail)


@dataclass(frozen=True)
class PairedDifference:
    """Method A vs method B on the same trials: A's success rate minus B's.

    Counts of the paired 2x2 table: ``both`` succeeded, ``only_a``, ``only_b``, ``neither``.
    """

    both: int
    only_a: int
    only_b: int
    neither: int
    diff: float  # fraction, A - B
    ci: tuple[float, float]  # Newcombe hybrid score interval for paired data (fractions)
    p_value: float  # exact McNemar

    @property
    def n(self) -> int:
        return self.both + self.only_a + self.only_b + self.neither


def paired_difference(pairs: list[tuple[bool, bool]], z: float = Z95) -> PairedDifference:
    """``pairs`` = (A succeeded, B succeeded) per shared trial."""
    both = sum(1 for a, b in pairs if a and b)
    only_a = sum(1 for a, b in pairs if a and not b)
    only_b = sum(1 for a, b in pairs if b and not a)
    neither = len(pairs) - both - only_a - only_b
    return paired_from_counts(both, only_a, only_b, neither, z)


def paired_from_counts(both: int, only_a: int, only_b: int, neither: int, z: float = Z95) -> PairedDifference:
    """Newcombe (1998) method 10: combine the two marginal Wilson intervals, allowing for the
    correlation between the paired outcomes (phi, with Newcombe's continuity correction)."""
    n = both + only_a + only_b + neither
    if n == 0:
        return PairedDifference(0, 0, 0, 0, math.nan, (math.nan, math.nan), 1.0)
    a_succ, b_succ = both + only_a, both + only_b
    p1, p2 = a_succ / n, b_succ / n
    l1, u1 = wilson(a_succ, n, z)
    l2, u2 = wilson(b_succ, n, z)
    a_fail, b_fail = n - a_succ, n - b_succ
    phi = 0.0
    if min(a_succ, a_fail, b_succ, b_fail) > 0:
        cross = both * neither - only_a * only_b
        if cross > n / 2:
            phi = (cross - n / 2) / math.sqrt(a_succ * a_fail * b_succ * b_fail)
        elif cross < 0:
            phi = cross / math.sqrt(a_succ * a_fail * b_succ * b_fail)
    d = p1 - p2
    lo = d - math.sqrt(max(0.0, (p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2))
    hi = d + math.sqrt(max(0.0, (p2 - l2) ** 2 - 2 * phi * (p2 - l2) * (u1 - p1) + (u1 - p1) ** 2))
    return PairedDifference(both, only_a, only_b, neither, d, (max(-1.0, lo), min(1.0, hi)),
                            mcnemar_exact(only_a, only_b))
