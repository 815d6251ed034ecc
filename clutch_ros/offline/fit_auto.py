"""Fit workflows: which keys to fit (oil film when the data shows it) and ``--law auto``.

:func:`film_shown` decides whether runs can identify the oil-film friction (Hypothesis 2): a
pressure-before-delta onset, i.e. the pack held under pressure at standstill for at least
``min_standstill`` seconds and then made to slip. Only then are ``friction.film_depth`` and
``friction.film_recovery_time`` fitted (a run without such an onset leaves them unobservable:
the film never thins), starting from a half-thinned film effect.

:func:`fit_auto` fits every passive spline law (``none``, ``ff_t``, ``ff_v``, ``coulomb``;
never the printed, non-passive Eqs. 29-30) on the fit runs, replays each fitted model on every
validation run at full rate (:func:`~clutch_ros.model.identification.evaluate`) and reports
the RMSE ratio model / Eq. 1 (same friction law) per law and run. The best law is the one
with the lowest mean ratio over the validation runs (over the fit runs when none are given).

Drivetrain compliance (:mod:`~clutch_ros.model.compliance`): ``compliance=True`` fits
``drivetrain.stiffness`` and ``drivetrain.damping`` too (:data:`COMPLIANCE_KEYS`), starting
from :data:`COMPLIANCE_START` when the base has the compliance off; otherwise they stay at the
base's values (fixed).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from clutch_ros.model.fit_data import IdentificationError
from clutch_ros.model.identification import FREE_PARAMETERS, FitOptions, FitResult, evaluate, fit
from clutch_ros.model.params import PASSIVE_LAWS, ClutchParams

__all__ = ["COMPLIANCE_KEYS", "COMPLIANCE_START", "compliance_start", "FILM_KEYS",
           "film_shown", "free_keys", "film_start", "LawScore", "AutoFitResult",
           "score_law", "fit_auto"]

#: oil-film keys fitted when the data shows a pressure-before-delta onset
FILM_KEYS = ("friction.film_depth", "friction.film_recovery_time")
#: drivetrain keys fitted with ``compliance=True`` (``clutch fit --fit-compliance``)
COMPLIANCE_KEYS = ("drivetrain.stiffness", "drivetrain.damping")
#: their start values when the base has them at 0: soft (500 N m/rad, 10 N m s/rad, c/k 20 ms),
#: so that the clutch sticks at the start point and both keys act on the torque
COMPLIANCE_START = {"drivetrain.stiffness": 500.0, "drivetrain.damping": 10.0}


def film_shown(runs, *, min_standstill: float = 0.3, standstill_speed: float = 0.05,
               slip_speed: float = 0.3, pressed_fraction: float = 0.2) -> bool:
    """Return True if a run holds pressure at standstill ≥ ``min_standstill`` s, then slips.

    Standstill: |ω| < ``standstill_speed`` [rad/s]; slipping: |ω| > ``slip_speed`` [rad/s];
    pressed: pressure above ``pressed_fraction`` of the run's highest pressure.
    """
    for run in runs:
        t = np.asarray(run.t, dtype=float)
        p = np.asarray(run.pressure, dtype=float)
        w = np.abs(np.asarray(run.slip_speed, dtype=float))
        if t.size < 3 or not np.isfinite(p).any():
            continue
        pressed = p > pressed_fraction * np.nanmax(p)
        since, held = None, 0.0  # start of the current pressed standstill, last one's length
        for k in range(t.size):
            if not pressed[k]:
                since, held = None, 0.0
            elif w[k] < standstill_speed:
                since = t[k] if since is None else since
                held = t[k] - since
            else:
                since = None
                if w[k] > slip_speed:
                    if held >= min_standstill:
                        return True
                    held = 0.0
    return False


def free_keys(law: str, runs, fixed: Sequence[str] = (), *,
              compliance: bool = False) -> list[str]:
    """Return the keys to fit for ``law``: its free parameters, plus the film if shown.

    ``compliance``: the drivetrain stiffness and damping too.
    """
    keys = list(FREE_PARAMETERS[law])
    if film_shown(runs):
        keys += list(FILM_KEYS)
    if compliance:
        keys += list(COMPLIANCE_KEYS)
    return [k for k in keys if k not in fixed]


def compliance_start(base: ClutchParams, keys) -> dict:
    """Start values for the drivetrain keys being fitted that are 0 in ``base``."""
    flat = base.to_flat()
    return {k: v for k, v in COMPLIANCE_START.items() if k in keys and not flat[k] > 0.0}


def film_start(base: ClutchParams, keys) -> dict:
    """Start values for the film keys: half a thinned film when the base has it off."""
    if "friction.film_depth" in keys and not base.friction.film_depth > 0.0:
        return {"friction.film_depth": 0.5}
    return {}


@dataclass
class LawScore:
    """One law of an auto fit: the fit and its RMSE ratio model / Eq. 1 per validation run."""

    law: str
    result: FitResult | None
    ratios: dict[str, float] = field(default_factory=dict)
    rmse: dict[str, float] = field(default_factory=dict)
    reference_rmse: dict[str, float] = field(default_factory=dict)
    error: str = ""

    @property
    def mean_ratio(self) -> float:
        """Mean of the ratios (inf when the law failed)."""
        return float(np.mean(list(self.ratios.values()))) if self.ratios else float("inf")

    @property
    def worst_ratio(self) -> float:
        """Largest ratio (inf when the law failed)."""
        return max(self.ratios.values()) if self.ratios else float("inf")

    def to_dict(self) -> dict:
        """Plain-JSON form."""
        return {"law": self.law, "error": self.error, "ratios": self.ratios,
                "rmse_nm": self.rmse, "reference_rmse_nm": self.reference_rmse,
                "mean_ratio": self.mean_ratio, "worst_ratio": self.worst_ratio,
                "fit": None if self.result is None else self.result.to_dict()}


@dataclass
class AutoFitResult:
    """Every law's score and the best one."""

    scores: list[LawScore]
    best: LawScore
    validated_on: list[str]

    def lines(self) -> list[str]:
        """Human-readable table: ratio per law per run, mean, worst."""
        names = self.validated_on
        out = ["RMSE ratio model / Eq. 1 (same friction law) per validation run:"]
        for s in self.scores:
            if s.error:
                out.append(f"  {s.law:8s} failed: {s.error}")
                continue
            cells = " ".join(f"{n}={s.ratios[n]:.3f}" for n in names)
            out.append(f"  {s.law:8s} mean {s.mean_ratio:.3f} worst {s.worst_ratio:.3f}  "
                       f"{cells}")
        out.append(f"best: {self.best.law} (mean ratio {self.best.mean_ratio:.3f})")
        return out


def score_law(law: str, result: FitResult, runs) -> LawScore:
    """Replay the fitted model on ``runs``; ratio = RMSE model / RMSE Eq. 1 per run."""
    score = LawScore(law, result)
    for run in runs:
        ev = evaluate(result.params, run)
        score.rmse[run.name] = ev.rmse
        score.reference_rmse[run.name] = ev.reference_rmse
        score.ratios[run.name] = (ev.rmse / ev.reference_rmse if ev.reference_rmse > 0.0
                                  else float("inf"))
    return score


def fit_auto(runs, validation_runs, base: ClutchParams, *, laws: Sequence[str] = PASSIVE_LAWS,
             fixed: Sequence[str] = (), options: FitOptions | None = None,
             compliance: bool = False) -> AutoFitResult:
    """Fit each law on ``runs``, score it on ``validation_runs`` (module docstring)."""
    targets = list(validation_runs) or list(runs)
    names = [r.name for r in targets]
    shared = sorted({n for n in names if names.count(n) > 1})
    if shared:  # the table is keyed by run name: two runs of one name would merge silently
        raise IdentificationError(f"validation runs share the name(s) {', '.join(shared)}: "
                                  "give each bag a distinct directory name")
    scores = []
    for law in laws:
        keys = free_keys(law, runs, fixed, compliance=compliance)
        try:
            result = fit(runs, law, base, fixed=fixed, free=keys,
                         start={**film_start(base, keys), **compliance_start(base, keys)},
                         options=options)
        except IdentificationError as err:
            scores.append(LawScore(law, None, error=str(err)))
            continue
        scores.append(score_law(law, result, targets))
    ok = [s for s in scores if s.result is not None]
    if not ok:
        raise IdentificationError("no law could be fitted: "
                                  + "; ".join(f"{s.law}: {s.error}" for s in scores))
    best = min(ok, key=lambda s: s.mean_ratio)
    return AutoFitResult(scores, best, [r.name for r in targets])
