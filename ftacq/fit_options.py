"""The choices a calibration fit takes, declared once: the fits check them, the CLI offers them (``--method``,
``--drift`` of ``ftacq identify`` and ``ftacq calibrate``). A light module (no numpy), so building the parsers
imports no fit."""

from __future__ import annotations

METHODS = ("auto", "srom", "lrom")
"""First estimate of the weight in the base frame (:func:`ftacq.identification.identify`): SROM (the 24 special
orientations), LROM (any orientations), or auto (SROM when all 24 are present)."""
DRIFT_MODELS = ("auto", "none", "linear")
"""``drift``: "linear" models a linear bias drift over the recording, "none" does not, "auto" does when the data
show it (the full run: residuals trending significantly and beyond the drift warning thresholds,
:mod:`ftacq.identification.trend`; the quick run: significant rates, :mod:`ftacq.dynamics.drift_terms`)."""

__all__ = ["METHODS", "DRIFT_MODELS"]
