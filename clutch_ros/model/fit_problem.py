"""The fit's least-squares problem: residuals of the scaled parameters, and their bounds.

:func:`clutch_ros.model.identification.fit` minimises the residuals of :class:`FitProblem`
with :func:`scipy.optimize.least_squares`. Units: time [s], pressure [Pa], torque [N m].

Residuals: measured − modelled torque [N m] over all runs, plus, where a run carries a P_diff
measurement (FlexiForce-derived, :mod:`~clutch_ros.model.calibration`),
``pdiff_weight · g · (P_diff,measured − P_diff,model)`` with ``g = 2 μ_ref R_e N A`` [N m/Pa]
(the torque one pascal of actuating pressure gives), so both terms are in N m. The model is
the estimator's own (:func:`~clutch_ros.model.simulate.simulate_columns`, the drivetrain
compliance when enabled), block-averaged onto the fit grid
(:func:`~clutch_ros.model.fit_data.model_block_means`).

A FlexiForce calibration fitted against the actuating force (thesis §5.5) assumes that the
rear disc carries the same force as the front one, so each disc's estimate is off by an
unknown gain (the average spline loss, sensor drift) and a raw P_diff carries a bias of the
order of 1 bar that would pull the friction law away from the torque. When a run gives the
front and rear pressures separately, the model P_diff is therefore compared as
``c_f · P_front,model − c_r · P_rear,model`` with per-run disc gains ``(c_f, c_r)`` solved by
linear least squares inside every residual evaluation (variable projection;
``pdiff_disc_gains``): P_diff informs the *dynamics* of the spline loss (its sign changes
between compression and rebound), not its absolute level — what the thesis trusts it for.

Parameterisation (:data:`TRANSFORM`): positive parameters (μ_ref, κ, τ, μ_s, c) are fitted as
``log(v / v0)``, the signed ones as ``(v − v0) / scale`` (1e-3 1/°C for the temperature slope,
0.01 for the pressure loss), so every variable is O(1) and one finite-difference step (1e-3)
suits all. Bounds: the ranges of :data:`~clutch_ros.model.params.PARAMETER_SPECS`, the
cross-key rules of :class:`~clutch_ros.model.params.ClutchParams` (μ_ref ≥ μ_min, a pressure
loss that keeps the torque rising up to ``max_pressure``) and three decades either side of
the start for the log parameters.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from clutch_ros.model import kernel
from clutch_ros.model.compliance import comply
from clutch_ros.model.fit_data import FitOptions, model_block_means
from clutch_ros.model.pack import PackModel
from clutch_ros.model.params import PARAMETER_SPECS, ClutchParams
from clutch_ros.model.simulate import simulate, simulate_columns

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from clutch_ros.model.arraytypes import FloatArray
    from clutch_ros.model.fit_data import Segment

__all__ = ["TRANSFORM", "FitProblem"]

#: fittable key -> (log parameterisation, linear scale of the signed ones)
TRANSFORM = {
    "friction.mu_ref": (True, 1.0),
    "friction.temperature_slope": (False, 1e-3),
    "friction.pressure_loss_at_ref": (False, 0.01),
    "spline.gain": (True, 1.0),
    "spline.time_constant": (True, 1.0),
    "spline.friction_coefficient": (True, 1.0),
    "clutch.lamella_damping": (True, 1.0),
    "friction.film_depth": (False, 0.1),
    "friction.film_recovery_time": (True, 1.0),
    "friction.film_thinning_time": (True, 1.0),
    "drivetrain.stiffness": (True, 1.0),
    "drivetrain.damping": (True, 1.0),
}
_LOG_SPAN = math.log(1e3)  # log parameters may move three decades either way


class FitProblem:
    """Residuals of the scaled parameter vector z over the selected segments.

    Args:
        base: the start parameters (``z = 0``) and everything not fitted
        keys: the fitted dotted keys (of :data:`TRANSFORM`), in the order of z
        segments: the prepared fit segments (:func:`~clutch_ros.model.fit_data.prepare_segments`)
        opts: :class:`~clutch_ros.model.fit_data.FitOptions` (P_diff weight, transition)

    """

    def __init__(self, base: ClutchParams, keys: Sequence[str], segments: Sequence[Segment],
                 opts: FitOptions) -> None:
        self.base = base
        self.keys = tuple(keys)
        self.segments = segments
        self.opts = opts
        flat = base.to_flat()
        self.v0 = np.array([float(flat[k]) for k in self.keys])
        self.log = np.array([TRANSFORM[k][0] for k in self.keys])
        self.scale = np.array([TRANSFORM[k][1] for k in self.keys])
        self.lower, self.upper = self._bounds()
        pk = base.pack
        self.torque_per_pa = (2.0 * base.friction.mu_ref * pk.effective_radius
                              * pk.lamella_count * pk.piston_area)
        self.calls = 0
        self._lock = threading.Lock()  # calls is counted from the Jacobian's threads too
        self.gains: dict[int, tuple[float, float]] = {}
        self.n_torque = int(sum(int((s.fit & np.isfinite(s.torque)).sum()) for s in segments))
        self.n_pdiff = int(sum(int((s.fit & np.isfinite(s.pdiff)).sum()) for s in segments
                               if s.pdiff is not None)) if opts.pdiff_weight > 0.0 else 0

    def _bounds(self) -> tuple[FloatArray, FloatArray]:
        lo: list[float] = []
        hi: list[float] = []
        fr, pk = self.base.friction, self.base.pack
        for key, v0, log, scale in zip(self.keys, self.v0, self.log, self.scale):
            spec = PARAMETER_SPECS[key]
            vmin = spec.minimum if spec.minimum is not None else -math.inf
            vmax = spec.maximum if spec.maximum is not None else math.inf
            if key == "friction.mu_ref":
                vmin = max(vmin, fr.mu_min)
            if key == "friction.pressure_loss_at_ref":
                vmax = min(vmax, 0.999 * fr.pressure_ref / (2.0 * pk.max_pressure))
            if key == "spline.time_constant":
                vmin, vmax = max(vmin, 1e-3), min(vmax, 1e3)
            if log:
                a = math.log(max(vmin, v0 * 1e-12, 1e-300) / v0) if vmin > 0 else -_LOG_SPAN
                b = math.log(vmax / v0) if math.isfinite(vmax) else _LOG_SPAN
                lo.append(max(a, -_LOG_SPAN) + 1e-9)
                hi.append(min(b, _LOG_SPAN) - 1e-9)
            else:
                lo.append((vmin - v0) / scale + 1e-9)
                hi.append((vmax - v0) / scale - 1e-9)
        return np.array(lo), np.array(hi)

    def values(self, z: ArrayLike) -> FloatArray:
        """Return the parameter values of the scaled vector ``z`` (parameter units)."""
        z = np.asarray(z, dtype=float)
        return np.where(self.log, self.v0 * np.exp(np.where(self.log, z, 0.0)),
                        self.v0 + self.scale * z)

    def params(self, z: ArrayLike) -> ClutchParams:
        """Return the base parameters with the values of ``z``."""
        vals = self.values(z)
        return self.base.updated({k: float(v) for k, v in zip(self.keys, vals)})

    def simulate(self, params: ClutchParams) -> list[tuple[FloatArray, ...]]:
        """Block-mean model outputs (torque, front and rear pressure) per segment."""
        model = PackModel(params, transition=self.opts.transition)
        out = []
        for s in self.segments:
            cols = np.empty((len(kernel.OUTPUT_COLUMNS), len(s)))
            if simulate_columns(params, s.t, s.p, s.omega, s.temp, cols, model=model):
                ys = (cols[0], cols[3], cols[4])  # torque, front and rear pressure
                pack = (cols[2], cols[5], cols[6])  # mu, compression, temperature
            else:
                sim = simulate(params, s.t, s.p, s.omega, s.temp, model=model)
                ys = (sim.torque, sim.front_pressure, sim.rear_pressure)
                pack = (sim.mu, sim.compression, sim.lamella_temperature)
            if params.drivetrain.enabled:  # the torque through the drivetrain compliance
                ys = (comply(params, s.t, s.omega, ys[0], pack), ys[1], ys[2])
            out.append(tuple(model_block_means(y, s.w) for y in ys))
        return out

    def residuals_parts(self, params: ClutchParams,
                        record: dict[int, tuple[float, float]] | None = None,
                        ) -> tuple[list[FloatArray], list[FloatArray]]:
        """Torque residuals [N m] and P_diff residuals [Pa], one array per segment.

        ``record``: a dict that receives the fitted front/rear disc gains per run (the final
        evaluation's; the solver's evaluations, some of them in threads, record none).
        """
        torque_res: list[FloatArray] = []
        pdiff_res: list[FloatArray] = []
        rows: dict[int, list[tuple[int, FloatArray, FloatArray, FloatArray]]] = {}
        for i, (s, (tq, front, rear)) in enumerate(zip(self.segments, self.simulate(params))):
            ok = s.fit & np.isfinite(s.torque)
            torque_res.append(s.torque[ok] - tq[ok])
            pdiff_res.append(np.zeros(0))
            if s.pdiff is not None and self.n_pdiff:
                okp = s.fit & np.isfinite(s.pdiff)
                if s.discs:
                    rows.setdefault(s.run, []).append((i, s.pdiff[okp], front[okp], rear[okp]))
                else:
                    pdiff_res[i] = s.pdiff[okp] - (front[okp] - rear[okp])
        for run, parts in rows.items():
            meas = np.concatenate([p[1] for p in parts])
            design = np.column_stack([np.concatenate([p[2] for p in parts]),
                                      -np.concatenate([p[3] for p in parts])])
            gains = np.ones(2)
            if meas.size >= 2 and np.linalg.matrix_rank(design) == 2:
                gains = np.linalg.lstsq(design, meas, rcond=None)[0]
            if record is not None:
                record[run] = (float(gains[0]), float(gains[1]))
            for i, pd, front, rear in parts:
                pdiff_res[i] = pd - (gains[0] * front - gains[1] * rear)
        return torque_res, pdiff_res

    def __call__(self, z: FloatArray) -> FloatArray:
        """Return the weighted residuals [N m] at ``z`` (least_squares' objective)."""
        with self._lock:
            self.calls += 1
        torque_res, pdiff_res = self.residuals_parts(self.params(z))
        parts = torque_res + [r * (self.opts.pdiff_weight * self.torque_per_pa)
                              for r in pdiff_res]
        return np.concatenate(parts)
