"""What a run's energy and angular-momentum histories say: their change, absolute and (where the
initial value is not near zero) relative, and what may change them. Shared by the summaries
(:mod:`.output`, the command line) and the drift plots (:mod:`.history_plots`)."""

from __future__ import annotations

import numpy as np


def near_zero(values, initial) -> bool:
    """Whether `initial` (a scalar, or a vector of `values`' rows) is near zero beside the history
    `values`: below a tenth of the largest value the run reaches. A run from rest (or from an
    orbit's slow turn) starts so, and a change relative to it would be huge and mean nothing."""
    values = np.asarray(values, float)
    size = float(np.linalg.norm(initial))
    peak = float(np.nanmax(np.abs(values))) if values.ndim == 1 else float(np.nanmax(np.linalg.norm(values, axis=-1)))
    return not (size > 0 and size >= 0.1 * peak)


def change_text(values, initial, unit: str) -> str:
    """``max change <abs> <unit>`` and, where the initial value is not :func:`near_zero`,
    ``(<rel> of the initial value)``."""
    values = np.asarray(values, float)
    change = (
        float(np.nanmax(np.abs(values - initial)))
        if values.ndim == 1
        else float(np.nanmax(np.linalg.norm(values - initial, axis=-1)))
    )
    text = f"max change {change:.3e} {unit}"
    if not near_zero(values, initial):
        text += f" ({change / float(np.linalg.norm(initial)):.3e} of the initial value)"
    return text


def drift_causes(model) -> tuple[list[str], list[str]]:
    """Why a run's energy and its angular momentum may change: ``(energy causes, momentum
    causes)`` of `model` (prescribed hinges, control laws and external loads do work, dampers
    dissipate; external loads and laws that act on the bodies from outside turn the momentum)."""
    energy, momentum = [], []
    if model is None:
        return energy, momentum
    if model.prescribed:
        energy.append("prescribed hinges do work")
    if getattr(model, "law", None) is not None or getattr(model, "controller", None) is not None:
        energy.append("control laws do work")
    if model.loads is not None:
        energy.append("external loads do work")
        momentum.append("external loads")
    sprung = np.asarray(model.sprung, int) - 1 if model.sprung else np.zeros(0, int)
    if sprung.size and np.any(np.asarray(model.damping)[sprung] != 0):
        energy.append("dampers dissipate")
    return energy, momentum
