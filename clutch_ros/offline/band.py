"""The torque band's error model identified on the estimate the node will publish.

The estimator node adapts online by default while a torque sensor is there (``adapt.enabled``,
:mod:`clutch_ros.model.adaptation`), and ``modelled_torque_std`` must be the 1-sigma error of
the torque it publishes: the adapted one. :func:`fit_band` replays the fitting bags as the node
runs them under one of :data:`BAND_MODES` (each bag with a fresh estimator, as a node started
per run) and identifies the error model on those residuals
(:func:`clutch_ros.offline.replay.fit_error_model_on_series`); :func:`band_extra` gives the
``adapt.*`` values that make the node run that mode, for the parameter file ``clutch fit``
writes beside ``uncertainty.*``, so the node publishes the band of the estimate it was
identified on.

:func:`cross_validate_band` scores a choice of the error model (its form, its settings, the
fitting runs themselves) on the fitting runs only: each run held out in turn, the model fitted
on the others. Choices are made on it, never on the runs the band is evaluated on.

Modes: ``fixed`` (no adaptation: ``adapt.enabled`` false), ``adapted`` (the friction scale:
the node's default), ``adapted_gain`` (the friction scale and the spline gain:
``adapt.spline_gain``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from clutch_ros.errors import ConfigError
from clutch_ros.model import uncertainty as unc
from clutch_ros.model.adaptation import AdaptationSettings
from clutch_ros.model.uncertainty import DEFAULTS, ErrorModel
from clutch_ros.offline.adapt import adaptive_replay
from clutch_ros.offline.replay import (
    fit_error_model_on_bags,
    fit_error_model_on_series,
    published_rows,
    replay_bag,
    stamps_s,
)

__all__ = ["BAND_MODES", "band_extra", "band_mode", "band_settings", "cross_validate_band",
           "fit_band", "replay_series", "score_band"]

#: How the estimate the band belongs to is computed (module docstring); the first: default.
BAND_MODES = ("adapted", "adapted_gain", "fixed")


def band_settings(mode: str) -> AdaptationSettings | None:
    """Return the adaptation of ``mode`` (None: the fixed model).

    Raises:
        ConfigError: an unknown mode.

    """
    if mode not in BAND_MODES:
        raise ConfigError(f"unknown band mode {mode!r}; known: {', '.join(BAND_MODES)}")
    if mode == "fixed":
        return None
    return AdaptationSettings(spline_gain=mode == "adapted_gain")


def band_extra(mode: str) -> dict[str, Any]:
    """Return the node's ``adapt.*`` values that run ``mode`` (for a parameter file)."""
    settings = band_settings(mode)
    return {"adapt.enabled": settings is not None,
            "adapt.spline_gain": settings is not None and settings.spline_gain}


def band_mode(flat: Any) -> str:
    """Return the mode the ``adapt.*`` of a parameter file (dotted keys) run.

    The inverse of :func:`band_extra`; absent keys take the node's defaults (``adapted``).
    """
    if not flat.get("adapt.enabled", True):
        return "fixed"
    return "adapted_gain" if flat.get("adapt.spline_gain", False) else "adapted"


def replay_series(bag: str | Path, params: Any, mode: str) -> dict[str, np.ndarray]:
    """Replay one bag as the node runs ``mode`` (adaptive: a fresh estimator).

    Returns:
        ``t`` [s], ``modelled`` and ``measured`` [N m] (``modelled`` NaN on the rows the node
        would not publish), ``slip`` (``slip_speed_filtered``) [rad/s] and ``pressure``
        (actuating) [Pa], one row per input sample.

    """
    settings = band_settings(mode)
    if settings is None:
        result = replay_bag(bag, params, per_lamella=False, pipeline=False)
    else:
        result = adaptive_replay([bag], params, settings)[0].result
    b = result.batch
    return {"t": stamps_s(result.rig),
            "modelled": np.where(published_rows(b), b.modelled_torque, np.nan),
            "measured": np.asarray(b.measured_torque, dtype=float),
            "slip": np.asarray(b.slip_speed_filtered, dtype=float),
            "pressure": np.asarray(b.actuating_pressure, dtype=float)}


def fit_band(bags: Any, params: Any, mode: str = BAND_MODES[0],
             base: ErrorModel = DEFAULTS) -> ErrorModel:
    """Identify the error model on ``bags`` replayed as the node runs ``mode`` (docstring).

    ``fixed`` is :func:`~clutch_ros.offline.replay.fit_error_model_on_bags`; the others join
    each bag's adaptive replay as it joins its bags.
    """
    if band_settings(mode) is None:
        return fit_error_model_on_bags(bags, params, base)
    return fit_error_model_on_series(
        [_part(replay_series(bag, params, mode)) for bag in bags], base)


def _part(series: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    return series["t"], series["modelled"], series["measured"], series["slip"]


def score_band(model: ErrorModel, series: dict[str, np.ndarray]) -> dict[str, Any]:
    """Return the band's coverage and mean negative log-likelihood on one run.

    ``series`` is one :func:`replay_series`; the result is
    :func:`~clutch_ros.model.uncertainty.coverage`'s dict, ``nll`` [nats per sample] (of the
    zero-mean normal of the published std) and ``nll_predictive`` (of the residual's predictive
    ``N(g M, v)``, :mod:`clutch_ros.model.recent_error`; ``nll`` when ``g M`` is 0).
    """
    t, modelled, slip = series["t"], series["modelled"], series["slip"]
    measured = series["measured"]
    est = unc.TorqueStd(model)
    std, offset, spread = (np.full(len(t), np.nan) for _ in range(3))
    for i in range(len(t)):  # torque_std's loop, keeping the predictive of each residual
        std[i] = est.update(float(t[i]), float(modelled[i]), float(slip[i]), float(measured[i]))
        offset[i], spread[i] = est.predictive
    out = unc.coverage(measured, modelled, std, unc.phases(t, series["pressure"], slip))
    out["nll"] = unc.negative_log_likelihood(measured, modelled, std)
    out["nll_predictive"] = unc.negative_log_likelihood(measured, modelled + offset, spread)
    return out


def cross_validate_band(bags: Any, params: Any, mode: str = BAND_MODES[0],
                        base: ErrorModel = DEFAULTS) -> list[dict[str, Any]]:
    """Leave one fitting run out: per bag, :func:`score_band` of the model fitted on the others.

    Every bag is replayed once as the node runs ``mode`` (a fresh estimator per bag, as
    :func:`fit_band`); the error model of each held-out bag is fitted on the other bags'
    series. Returns one dict per bag: ``run`` (the bag's name) and the scores.

    Raises:
        ConfigError: fewer than two bags (nothing to hold out).

    """
    bags = list(bags)
    if len(bags) < 2:
        raise ConfigError(f"cross-validation needs at least two fitting runs, got {len(bags)}")
    series = [replay_series(bag, params, mode) for bag in bags]
    rows = []
    for i, bag in enumerate(bags):
        model = fit_error_model_on_series(
            [_part(s) for j, s in enumerate(series) if j != i], base)
        rows.append({"run": Path(bag).name, **score_band(model, series[i])})
    return rows
