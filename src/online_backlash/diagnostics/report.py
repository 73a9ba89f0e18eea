"""A Markdown report of a :class:`~online_backlash.diagnostics.diagnosis.Diagnosis` (no printing here)."""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from .diagnosis import Diagnosis
from .residuals import Profile, profile


def _fmt(value: Any) -> str:
    return json.dumps(value, default=float, allow_nan=True)


def _peak(p: Profile) -> str:
    """The largest absolute bin mean and where it sits."""
    i = int(np.nanargmax(np.abs(p.mean_deg)))
    return f"{p.mean_deg[i]:+.4f} at {p.centers[i]:.4g}"


def _along(diagnosis: Diagnosis, step: Any, before: np.ndarray, after: np.ndarray) -> str:
    """The residual just before and after a step, binned against the variable the term acts along."""
    name, unit, values = diagnosis.axis(step)
    pb, pa = profile(before, values, name, unit), profile(after, values, name, unit)
    return f"{name} ({unit}): largest bin mean {_peak(pb)} before, {_peak(pa)} after (deg)"


def markdown_report(diagnosis: Diagnosis, source: str | os.PathLike[str] | None = None, plot: str | None = None) -> str:
    """The loop's findings as Markdown: summary table, one section per term, the play guard's verdict."""
    d = diagnosis.as_dict()
    lines = ["# Residual diagnosis", ""]
    if source is not None:
        lines += [f"Log: `{os.fspath(source)}` ({d['samples']} samples)", ""]
    lines += [
        "| quantity | before | after |",
        "|---|---|---|",
        f"| residual RMS, deg | {d['rms_before_deg']:.5f} | {d['rms_after_deg']:.5f} |",
        f"| backlash (play), deg | {d['backlash_before_deg']:.4f} | {d['backlash_after_deg']:.4f} |",
        "",
        f"Noise floor: {d['noise_floor_deg']:.5f} deg (load encoder step {d['load_step_deg']:.5f} deg, "
        f'sample noise {d["load_noise_deg"]:.5f} deg). The "before" is the four backlash parameters '
        "refitted on the simulation (free-run) residual.",
        "",
    ]
    start = d["initial_state"]
    if start["estimated"]:
        lines += [
            f"Record start: the load was moving in the dead band ({start['velocity_deg_s']:.3g} deg/s, offset "
            f"{start['offset_deg']:.2g} deg, from {start['starts_moving_after_s']:.3g} s) "
            f"for {start['samples']} samples "
            "before a flank caught it. Estimated as the "
            f"model's initial state (residual there {start['rms_at_rest_deg']:.4f} -> "
            f"{start['rms_deg']:.4f} deg RMS) and "
            "taken out of the residual before and after alike; not an effect.",
            "",
        ]
    if d["screened_cycles"] is not None:
        lines += [
            f"Search: the candidates were scored and refitted on {d['screened_cycles']} of the record's "
            f"{diagnosis.cycles} reversal cycles, spread over it; each effect chosen was then detected again, and the "
            "terms fitted, on every sample.",
            "",
        ]
    if plot:
        lines += [f"![residual before and after]({plot})", ""]
    lines += [
        "Where the residual sits: the largest mean of the simulation residual in 40 bins of each variable, deg.",
        "",
        "| against | before | after |",
        "|---|---|---|",
    ]
    for name, (before, after) in diagnosis.profiles().items():
        lines.append(f"| {name} ({before.unit}) | {_peak(before)} | {_peak(after)} |")
    lines.append("")
    if not d["effects"] and not d["unexplained"]:
        lines += ["Nothing significant is missing from the model: no effect was added.", ""]
    steps = sorted(
        [("effect", e) for e in d["effects"]] + [("unexplained", e) for e in d["unexplained"]],
        key=lambda s: s[1]["step"],
    )
    along = {s.number: _along(diagnosis, s, before, after) for s, before, after in diagnosis.step_residuals()}
    for kind, e in steps:
        lines += _step_section(kind, e, along[e["step"]])
    return "\n".join(lines)


def _step_section(kind: str, e: dict[str, Any], along: str) -> list[str]:
    """The Markdown lines of one step: ``kind`` (``"effect"`` or ``"unexplained"``), ``e`` the step's JSON
    object, ``along`` the residual against the term's own axis (:func:`_along`)."""
    ev = e["evidence"]
    title = (
        "effect" if kind == "effect" else "not separable" if e["name"] == "not_separable" else "unexplained structure"
    )
    split = ev["heldout_split"]
    lines = [
        f"## Step {e['step']}: {title} `{e['name']}`",
        "",
        f"- evidence: {ev['summary']}; criterion delta_bic_eff = {ev['delta_bic_eff']:.0f} "
        f"(threshold {ev['threshold']:.0f}), {ev['share_of_residual_explained']:.1%} of the residual explained",
        f"- held out: {ev['heldout_gain']:.1%} of the squared error removed on "
        f"{split.get('split', 'blocks')} it was not fitted on "
        f"({split.get('folds', '?')} folds, {split.get('cycles', '?')} cycles); "
        f"{ev['heldout_gain_in_final_model']:.1%} "
        "given all the other terms of the final model",
        f"- residual against its own axis, {along}",
        f"- residual RMS {e['rms_before_deg']:.5f} -> {e['rms_after_deg']:.5f} deg; "
        f"play {e['backlash_before_deg']:.4f} -> {e['backlash_after_deg']:.4f} deg",
        f"- play variance inflation {ev['play_variance_inflation']:.1f}, "
        f"play standard error {ev['play_std_deg']:.2g} deg: "
        + ("separable from the play" if ev["play_separable"] else ev["note"]),
    ]
    if "where" in e:
        lines.append(f"- where: {e['where']}; no effect of the library explains it, a generic term closes it")
    lines += [f"- parameters: `{_fmt(e['parameters'])}`", ""]
    return lines
