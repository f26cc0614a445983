"""The verdict's ``sensor`` line: the sensor check's gains and cross-talk against the sensor's stated accuracy.

The identification's sensor check (ftacq.identification.sensor_gain) leaves ``metadata["sensor_check"]``: the force
gain/cross-talk matrix C (symmetric; trace 3 without a reference weight), its covariance, and the torque gains'
differences that the centre of mass's lever arm shows. Each figure judged here is a lower bound of an error of the
sensor's own calibration, with its 1σ:

- with a reference weight, each force gain C_kk − 1;
- for each pair of force axes C_kk − C_jj (without a reference only these ratios are known; with one they are still
  known more precisely than the gains): at least one of the two gains is off by half that, whatever the tool weighs;
- each cross-talk C_jk (the symmetric part: one-way cross-talk x between two axes shows as x/2, the rest is the
  mounting rotation); at least one of the two directions is that large;
- the torque gains' differences d_k − d_j (half of it, as for the force gains' ratios).

A figure is beyond the accuracy a when it exceeds a by more than 3σ: WARN; beyond 2a by more than 3σ: FAIL (the
sensor needs recalibrating). Otherwise PASS. ATI states accuracy as a percentage of full scale per axis; a gain or
cross-talk error of x % gives an error of x % of full scale at full load, so it is compared with x directly.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2
from ftacq.channels import FORCE_AXES
from ftacq.verdict import FAIL, PASS, WARN, Finding

WARN_SIGMAS = 3.0
"""A figure counts beyond a limit when it exceeds it by more than this many σ."""
FAIL_FACTOR = 2.0
"""Beyond this many times the stated accuracy (by more than WARN_SIGMAS σ) is a FAIL."""


def _items(check: Mapping[str, Any]) -> list[dict]:
    """Return every judged figure: {"text", "bound" (fraction), "sigma", "value", "load" (the tool's weight in N, or
    its torque across the pair in N·m, that the fraction multiplies), "unit"}."""
    weight_n = float(check.get("mass_kg", 0.0)) * STANDARD_GRAVITY_M_S2
    gain = np.asarray(check["force_gain"], dtype=float)
    cov = np.asarray(check["force_gain_covariance"], dtype=float)
    off_index = {(0, 1): 3, (0, 2): 4, (1, 2): 5}
    items = []
    if check.get("reference_mass_kg") is not None:
        for k in range(3):
            error, sigma = gain[k, k] - 1.0, float(np.sqrt(max(cov[k, k], 0.0)))
            items.append({"text": f"{FORCE_AXES[k]} gain {100 * abs(error):.2g} % {'high' if error > 0 else 'low'} "
                                  f"(± {100 * sigma:.2g} %)", "bound": abs(error), "sigma": sigma, "value": error,
                          "load": weight_n, "unit": "N"})
    for j, k in ((0, 1), (0, 2), (1, 2)):  # the gains' ratios
        difference = gain[k, k] - gain[j, j]
        sigma = float(np.sqrt(max(cov[j, j] + cov[k, k] - 2 * cov[j, k], 0.0)))
        high, low = (FORCE_AXES[k], FORCE_AXES[j]) if difference > 0 else (FORCE_AXES[j], FORCE_AXES[k])
        items.append({"text": f"{high} reads {100 * abs(difference):.2g} % more than {low} (± {100 * sigma:.2g} %): "
                              f"one of their gains is at least {50 * abs(difference):.2g} % off",
                      "bound": abs(difference) / 2, "sigma": sigma / 2, "value": difference, "load": weight_n,
                      "unit": "N"})
    for (j, k), index in off_index.items():
        value, sigma = gain[j, k], float(np.sqrt(max(cov[index, index], 0.0)))
        items.append({"text": f"cross-talk between {FORCE_AXES[j]} and {FORCE_AXES[k]} {100 * abs(value):.2g} % "
                              f"(± {100 * sigma:.2g} %)", "bound": abs(value), "sigma": sigma, "value": value,
                      "load": weight_n, "unit": "N"})
    for entry in check.get("torque_gain_differences", []):
        j, k = entry["axes"]
        value, sigma = float(entry["value"]), float(entry["sigma"])
        high, low = (k, j) if value > 0 else (j, k)
        items.append({"text": f"{high} reads {100 * abs(value):.2g} % more than {low} (± {100 * sigma:.2g} %; seen "
                              f"through the tool's {1000 * abs(entry['lever_m']):.0f} mm lever arm)",
                      "bound": abs(value) / 2, "sigma": sigma / 2, "value": value,
                      "load": weight_n * abs(float(entry["lever_m"])), "unit": "N·m"})
    return items


def sensor_finding(check: Mapping[str, Any], accuracy_percent: float | None = None,
                   tolerance: tuple[float, float] | None = None) -> Finding:
    """Judge the sensor check (``metadata["sensor_check"]``) against the stated accuracy (%, default the check's
    ``accuracy_percent`` or CELL.toml ``sensor.accuracy_percent``) and the model-mismatch ``tolerance`` (N, N·m;
    default CELL.toml ``sampling.mismatch_tolerance_*``): a figure is flagged only when the error it causes at this
    tool's weight is also beyond the tolerance, which a cable or the arm's own errors reach (module docstring)."""
    from ftacq.settings import SamplingConfig, SensorConfig

    if accuracy_percent is None:
        accuracy_percent = float(check.get("accuracy_percent") or SensorConfig.accuracy_percent)
    if tolerance is None:
        tolerance = (SamplingConfig.mismatch_tolerance_force_n, SamplingConfig.mismatch_tolerance_torque_nm)
    accuracy = accuracy_percent / 100.0
    items = _items(check)
    for item in items:
        beyond = item["bound"] - WARN_SIGMAS * item["sigma"]  # the error at least this large (3σ)
        limit = tolerance[0] if item["unit"] == "N" else tolerance[1]
        item["effect"] = beyond * item["load"]
        visible = item["effect"] > limit
        item["status"] = (FAIL if beyond > FAIL_FACTOR * accuracy and visible else
                          WARN if beyond > accuracy and visible else PASS)
        item["hidden"] = beyond > accuracy and not visible
    rank = {PASS: 0, WARN: 1, FAIL: 2}
    worst = max(items, key=lambda i: (rank[i["status"]], i["bound"] - WARN_SIGMAS * i["sigma"]))
    scale = ("absolute: reference weight" if check.get("reference_mass_kg") is not None
             else "without a reference weight only the gains' ratios are known")
    gain = np.asarray(check["force_gain"], dtype=float)
    sigma = np.asarray(check["force_gain_sigma"], dtype=float)
    details = (f"force gain matrix C (symmetric; {scale}) = {np.round(gain, 5).tolist()} ± "
               f"{np.round(sigma, 5).tolist()}; test of a perfect sensor χ² = {float(check.get('chi2', 0)):.1f} on "
               f"{check.get('dof')} degrees of freedom (p = {float(check.get('p_value', 1)):.2g}); each figure is a "
               f"lower bound of an error, WARN when beyond {accuracy_percent:g} % by more than {WARN_SIGMAS:g}σ and "
               f"the error it causes at this tool's weight beyond the tolerance ({tolerance[0]:g} N, "
               f"{tolerance[1]:g} N·m), FAIL beyond {FAIL_FACTOR * accuracy_percent:g} %")
    figures = {"accuracy_percent": accuracy_percent, "items": items, "significant": bool(check.get("significant")),
               "p_value": check.get("p_value"), "tolerance": list(tolerance)}
    certificate = f"certificate accuracy {accuracy_percent:g} %"
    if worst["status"] != PASS:
        more = sum(1 for i in items if i["status"] != PASS) - 1
        summary = (f"the sensor's own calibration is off: {worst['text']}; {certificate}"
                   + (f" (and {more} more beyond it)" if more > 0 else "")
                   + ("; have it recalibrated" if worst["status"] == FAIL else "; recheck it, or have it recalibrated"))
        return Finding("sensor", worst["status"], summary, details, figures)
    hidden = sorted((i for i in items if i["hidden"]), key=lambda i: -(i["bound"] - WARN_SIGMAS * i["sigma"]))
    if hidden:
        summary = (f"the data show {' and '.join(i['text'] for i in hidden[:2])}, beyond the {certificate}, but at "
                   f"this tool's weight that is at most {hidden[0]['effect']:.2g} {hidden[0]['unit']}, within the "
                   "model-mismatch tolerance: a cable, a flexible tool or the arm's own errors make errors that size; "
                   "check the sensor with a heavier reference weight")
    elif check.get("significant"):
        largest = max(items, key=lambda i: i["bound"] - WARN_SIGMAS * i["sigma"])
        summary = (f"the sensor's gains differ measurably from a perfect sensor but within its certificate: largest "
                   f"{largest['text']}; {certificate}; compensation does not correct it")
    else:
        force = [i for i in items if i["unit"] == "N"]
        summary = (f"the sensor's gains and cross-talk agree with a perfect sensor within the noise (force figures "
                   f"resolved to ± {100 * max(i['sigma'] for i in force):.2g} %; {certificate})")
    unresolved = [i for i in items if WARN_SIGMAS * i["sigma"] > accuracy]
    if unresolved:
        summary += (f"; {len(unresolved)} of {len(items)} figures not resolved to the accuracy (too light a tool or "
                    "too few poses)")
    return Finding("sensor", PASS, summary, details, figures)


def parse_reference_mass(text: str):
    """Return the :class:`ftacq.identification.sensor_gain.ReferenceWeight` of ``KG[±SIGMA]`` (``1.35``,
    ``1.35±0.002``, ``1.35+-0.002``). Raises ValueError saying what is wrong."""
    from ftacq.identification.sensor_gain import ReferenceWeight

    parts = str(text).replace("+-", "±").split("±")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"{text!r} is not KG or KG±SIGMA (e.g. 1.35 or 1.35±0.002)") from None
    if len(values) > 2 or not all(np.isfinite(values)) or values[0] <= 0.0 or (len(values) == 2 and values[1] < 0):
        raise ValueError(f"{text!r}: give a positive mass in kg and, optionally, ±its 1σ (e.g. 1.35±0.002)")
    return ReferenceWeight(values[0], values[1] if len(values) == 2 else 0.0)


def explained_fit(fit: Finding, check: Mapping[str, Any], tolerance: tuple[float, float]) -> Finding:
    """Return the ``fit`` finding with its cause named when it warns of a model mismatch that the sensor check
    explains (its own fit leaves scatter within the tolerance): the sensor's gains, which compensation does not
    correct. The status stays."""
    scatter = np.asarray(check.get("extra_scatter") or np.zeros(6), dtype=float)
    mismatch = fit.status == WARN and "mismatch" in fit.summary
    if not (mismatch and check.get("significant") and scatter.shape == (6,)
            and scatter[:3].max() <= tolerance[0] and scatter[3:].max() <= tolerance[1]):
        return fit
    summary = (fit.summary.split(": compensation")[0] + f": the sensor's own gains explain it (the sensor check's fit "
               f"leaves {scatter[:3].max():.3g} N, {scatter[3:].max():.3g} N·m; see the sensor line), and compensation "
               "does not correct them")
    return Finding(fit.check, fit.status, summary, fit.details, fit.figures)


__all__ = ["parse_reference_mass", "explained_fit", "sensor_finding", "WARN_SIGMAS", "FAIL_FACTOR"]
