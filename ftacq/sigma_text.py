"""Printing a value with its 1σ: the 1σ with two significant digits, the value to the same last decimal.

``ftacq tare`` and ``ftacq monitor`` print biases and bias offsets with their 1σ; a 1σ of 0.00045 N printed as
``0.0004`` (one significant digit) hides a factor of up to 2, and a value printed with fewer decimals than its 1σ
hides whether it is significant. Plain text, no device access.
"""

from __future__ import annotations

import math

SIGMA_DIGITS = 2
"""Significant digits of a printed 1σ."""
DEFAULT_DECIMALS = 4
"""Decimals when the 1σ is zero or not finite (nothing tells how many are meaningful)."""


def decimals_for(sigma: float, digits: int = SIGMA_DIGITS) -> int:
    """Return the decimals that print ``sigma`` with ``digits`` significant digits (≥ 0)."""
    sigma = abs(float(sigma))
    if not math.isfinite(sigma) or sigma == 0.0:
        return DEFAULT_DECIMALS
    places = max(0, digits - 1 - math.floor(math.log10(sigma)))
    if places and float(f"{sigma:.{places}f}") >= 10.0 ** (digits - 1 - places) * 10:  # 0.0995 rounds to 0.100
        places -= 1
    return places


def format_sigma(sigma: float, digits: int = SIGMA_DIGITS) -> str:
    """Return ``sigma`` in fixed notation with ``digits`` significant digits (``0.00045``, ``0.012``, ``1.5``)."""
    if not math.isfinite(float(sigma)):
        return str(float(sigma))
    return f"{abs(float(sigma)):.{decimals_for(sigma, digits)}f}"


def format_with_sigma(value: float, sigma: float, digits: int = SIGMA_DIGITS, sign: bool = True) -> str:
    """Return ``value±sigma``, the 1σ with ``digits`` significant digits and the value to the same decimal."""
    places = decimals_for(sigma, digits)
    return f"{float(value):{'+' if sign else ''}.{places}f}±{format_sigma(sigma, digits)}"


__all__ = ["SIGMA_DIGITS", "decimals_for", "format_sigma", "format_with_sigma"]
