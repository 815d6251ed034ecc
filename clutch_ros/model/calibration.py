"""FlexiForce calibration and lamella force estimation (thesis §5.5, Eqs. 6–10).

Units: voltages [V], forces [N], pressures [Pa], piston area [m²]. Sensor arrays are
``(n, 2k)``: the ``k`` sensors of the front (piston-side, lamella N) separator disc first,
then the ``k`` of the rear (lamella 1) disc, as ``RigState.ff_voltages`` orders them
(``k = 4`` on the thesis rig).

Each sensor's force-voltage law is a second-degree polynomial through the origin,
``F = a v² + b v`` (the thesis' datasheet curve and post-calibration, Figs. 23 and 42). With no
reference load cell the polynomials are fitted against the actuating force ``F_act = p A``
under one of two assumptions, each by linear least squares (columns ``v²`` and ``v``):

- **same force** (Eqs. 6–9): every sensor of a disc carries ``F_act / k`` and the sensors
  differ: one ``(a_n, b_n)`` per sensor from ``F_act / k = a_n v_n² + b_n v_n``.
- **same sensor** (Eq. 10): all sensors of a disc share one law and carry different forces:
  one ``(a, b)`` per disc from ``F_act = Σ_n (a v_n² + b v_n)``.

Both assume that the rear disc carries the same force as the front one on average (the pack
losses have vanished), so absolute front/rear levels and a persistent P_diff are not
trustworthy (thesis §5.5); the dynamics of P_diff are. :func:`compare_methods` fits both and
reports how far their pressure estimates differ ("if the measurements are sensitive to the
calibration method, a more conservative approach towards the result should be done").

Sample selection: ``mask`` restricts the fit; :func:`quasi_static_mask` keeps samples where
the pressure has been steady for a while, so the pack's transient lag (the front disc leads
F_act, the rear one lags it) does not bias the polynomials. Samples with a non-finite voltage
or force, and clipped voltages (≥ ``clip_voltage``), are always left out.

Estimation: the front/rear lamella force is the sum of its sensors' forces; the pressures are
force / A and ``P_diff = front − rear`` (thesis Fig. 20).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from clutch_ros.model.arraytypes import BoolArray, FloatArray
from clutch_ros.model.errors import CalibrationError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = [
    "CalibrationError",
    "SensorCalibration",
    "LamellaPressures",
    "CalibrationComparison",
    "calibrate",
    "calibrate_same_force",
    "calibrate_same_sensor",
    "compare_methods",
    "quasi_static_mask",
    "METHODS",
]

#: Calibration methods: "same_force" (Eqs. 6–9) and "same_sensor" (Eq. 10).
METHODS = ("same_force", "same_sensor")


@dataclass(frozen=True)
class LamellaPressures:
    """Pressures estimated from FlexiForce voltages [Pa], shape (n,) each.

    ``front``: on the front (piston-side) lamella; ``rear``: on the rear lamella;
    ``difference``: P_diff = front − rear; ``front_force``/``rear_force`` [N].
    """

    front: np.ndarray
    rear: np.ndarray
    difference: np.ndarray
    front_force: np.ndarray
    rear_force: np.ndarray


@dataclass(frozen=True)
class SensorCalibration:
    """A fitted calibration: ``F_i = a_i v_i² + b_i v_i`` for every sensor.

    Attributes:
        method: ``"same_force"`` or ``"same_sensor"``.
        coefficients: (2k, 2) ``[a_i, b_i]`` per sensor, front 1..k then rear 1..k
            (same_sensor: the disc's shared pair repeated) [N/V², N/V].
        sensors_per_lamella: k.
        samples: number of samples the fit used.
        rmse: per disc (front, rear), RMS of (fitted total force − F_act) over those
            samples [N].

    """

    method: str
    coefficients: np.ndarray
    sensors_per_lamella: int
    samples: int
    rmse: tuple[float, float]

    def sensor_forces(self, voltages: ArrayLike) -> FloatArray:
        """Return each sensor's force (n, 2k) [N] for voltages (n, 2k) [V]."""
        v = _voltages(voltages, 2 * self.sensors_per_lamella)
        a, b = self.coefficients[:, 0], self.coefficients[:, 1]
        return a * v * v + b * v

    def lamella_forces(self, voltages: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Return (front, rear) lamella forces (n,) [N]: the sums over each disc's sensors."""
        f = self.sensor_forces(voltages)
        k = self.sensors_per_lamella
        return f[:, :k].sum(axis=1), f[:, k:].sum(axis=1)

    def pressures(self, voltages: ArrayLike, piston_area: float) -> LamellaPressures:
        """Return front/rear lamella pressure and P_diff [Pa] for ``piston_area`` [m²]."""
        if not piston_area > 0.0:
            raise CalibrationError(f"piston area must be > 0 m^2, got {piston_area!r}")
        front, rear = self.lamella_forces(voltages)
        pf, pr = front / piston_area, rear / piston_area
        return LamellaPressures(pf, pr, pf - pr, front, rear)

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-friendly dict (coefficients as lists of [a, b])."""
        return {"method": self.method, "sensors_per_lamella": self.sensors_per_lamella,
                "coefficients": self.coefficients.tolist(), "samples": self.samples,
                "rmse_front_n": self.rmse[0], "rmse_rear_n": self.rmse[1]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SensorCalibration:
        """Inverse of :meth:`to_dict`."""
        coef = np.asarray(data["coefficients"], dtype=float)
        k = int(data.get("sensors_per_lamella", coef.shape[0] // 2))
        if coef.shape != (2 * k, 2) or not np.isfinite(coef).all():
            raise CalibrationError(f"coefficients must be a finite ({2 * k}, 2) array, got "
                                   f"shape {coef.shape}")
        method = str(data.get("method", "same_force"))
        if method not in METHODS:
            raise CalibrationError(f"unknown calibration method {method!r} "
                                   f"(one of {', '.join(METHODS)})")
        return cls(method, coef, k, int(data.get("samples", 0)),
                   (float(data.get("rmse_front_n", np.nan)),
                    float(data.get("rmse_rear_n", np.nan))))


@dataclass(frozen=True)
class CalibrationComparison:
    """Both calibrations fitted on the same data and how much their estimates differ.

    ``front_rms``, ``rear_rms``, ``difference_rms``: RMS over the fit samples of (same force −
    same sensor) for the front pressure, rear pressure and P_diff [Pa]; ``difference_max``:
    the largest |ΔP_diff| [Pa]; ``pdiff_correlation``: correlation of the two P_diff series
    (1 = same dynamics); ``relative``: ``difference_rms`` / RMS of the same-force P_diff.
    """

    same_force: SensorCalibration
    same_sensor: SensorCalibration
    front_rms: float
    rear_rms: float
    difference_rms: float
    difference_max: float
    pdiff_correlation: float
    relative: float
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-friendly dict."""
        return {"same_force": self.same_force.to_dict(),
                "same_sensor": self.same_sensor.to_dict(),
                "front_rms_pa": self.front_rms, "rear_rms_pa": self.rear_rms,
                "pdiff_rms_pa": self.difference_rms, "pdiff_max_pa": self.difference_max,
                "pdiff_correlation": self.pdiff_correlation, "pdiff_relative": self.relative,
                **self.extra}

    def summary(self) -> str:
        """One line: how sensitive the pressure estimates are to the method."""
        return (f"same force vs same sensor: front {self.front_rms / 1e5:.3f} bar, rear "
                f"{self.rear_rms / 1e5:.3f} bar, P_diff {self.difference_rms / 1e5:.3f} bar RMS "
                f"(max {self.difference_max / 1e5:.3f} bar, correlation "
                f"{self.pdiff_correlation:.3f})")


def _voltages(voltages: ArrayLike, width: int | None = None) -> FloatArray:
    v = np.asarray(voltages, dtype=float)
    if v.ndim != 2 or v.shape[1] < 2 or v.shape[1] % 2:
        raise CalibrationError(f"voltages must be an (n, 2k) array (front then rear sensors), "
                               f"got shape {v.shape}")
    if width is not None and v.shape[1] != width:
        raise CalibrationError(f"calibration is for {width} sensors, voltages have "
                               f"{v.shape[1]}")
    return v


def _select(voltages: ArrayLike, actuating_force: ArrayLike, mask: ArrayLike | None,
            clip_voltage: float) -> tuple[FloatArray, FloatArray]:
    v = _voltages(voltages)
    force = np.asarray(actuating_force, dtype=float)
    if force.shape != (v.shape[0],):
        raise CalibrationError(f"actuating force must have shape ({v.shape[0]},), got "
                               f"{force.shape}")
    ok = np.isfinite(force) & np.isfinite(v).all(axis=1) & (v < clip_voltage).all(axis=1)
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != ok.shape:
            raise CalibrationError(f"mask must have shape {ok.shape}, got {m.shape}")
        ok &= m
    v, force = v[ok], force[ok]
    if v.shape[0] < 10:
        raise CalibrationError(f"only {v.shape[0]} usable samples (finite, unclipped, selected); "
                               "need at least 10")
    loaded = force[force > 0.0]
    if loaded.size == 0 or np.ptp(force) < 0.2 * max(float(np.max(np.abs(force))), 1e-12):
        raise CalibrationError("the actuating force hardly varies: a polynomial through the "
                               "origin needs forces spread over the range (e.g. the "
                               "incremented-step sequence)")
    return v, force


def _lstsq(columns: FloatArray, target: FloatArray, what: str) -> FloatArray:
    scale = np.linalg.norm(columns, axis=0)
    if (scale <= 1e-12 * max(float(scale.max()), 1e-300)).any() or not scale.max() > 0.0:
        raise CalibrationError(f"{what}: voltage is always 0 V (dead or unconnected sensor)")
    cols = columns / scale
    sv = np.linalg.svd(cols, compute_uv=False)
    if sv[-1] < 1e-9 * sv[0]:
        raise CalibrationError(f"{what}: v and v² are collinear (the voltage takes a single "
                               "value), the polynomial is not determined")
    coef, *_ = np.linalg.lstsq(cols, target, rcond=None)
    out: FloatArray = coef / scale
    return out


def _names(k: int) -> list[str]:
    return [f"front {i + 1}" for i in range(k)] + [f"rear {i + 1}" for i in range(k)]


def _rmse_groups(coefficients: FloatArray, v: FloatArray, force: FloatArray,
                 k: int) -> tuple[float, float]:
    a, b = coefficients[:, 0], coefficients[:, 1]
    f = a * v * v + b * v
    out = []
    for g in (slice(0, k), slice(k, 2 * k)):
        err = f[:, g].sum(axis=1) - force
        out.append(float(np.sqrt(np.mean(err * err))))
    return out[0], out[1]


def calibrate_same_force(voltages: ArrayLike, actuating_force: ArrayLike,
                         mask: ArrayLike | None = None, *,
                         clip_voltage: float = 5.9) -> SensorCalibration:
    """Fit Eqs. 6–9: ``F_act / k = a_n v_n² + b_n v_n`` for each sensor n.

    Args:
        voltages: (n, 2k) [V], front sensors then rear sensors.
        actuating_force: (n,) F_act = p A [N].
        mask: optional (n,) bool, the samples to fit on.
        clip_voltage: samples with any voltage at or above this [V] are left out.

    """
    v, force = _select(voltages, actuating_force, mask, clip_voltage)
    k = v.shape[1] // 2
    coef = np.empty((2 * k, 2))
    for i, name in enumerate(_names(k)):
        x = v[:, i]
        coef[i] = _lstsq(np.column_stack([x * x, x]), force / k, f"sensor {name}")
    return SensorCalibration("same_force", coef, k, int(v.shape[0]),
                             _rmse_groups(coef, v, force, k))


def calibrate_same_sensor(voltages: ArrayLike, actuating_force: ArrayLike,
                          mask: ArrayLike | None = None, *,
                          clip_voltage: float = 5.9) -> SensorCalibration:
    """Fit Eq. 10: ``F_act = Σ_n (a v_n² + b v_n)``, one (a, b) per disc (front, rear).

    Arguments as :func:`calibrate_same_force`.
    """
    v, force = _select(voltages, actuating_force, mask, clip_voltage)
    k = v.shape[1] // 2
    coef = np.empty((2 * k, 2))
    for g, name in ((slice(0, k), "front"), (slice(k, 2 * k), "rear")):
        x = v[:, g]
        ab = _lstsq(np.column_stack([(x * x).sum(axis=1), x.sum(axis=1)]), force,
                    f"{name} sensors")
        coef[g] = ab
    return SensorCalibration("same_sensor", coef, k, int(v.shape[0]),
                             _rmse_groups(coef, v, force, k))


def calibrate(voltages: ArrayLike, actuating_force: ArrayLike, method: str = "same_force",
              mask: ArrayLike | None = None, *,
              clip_voltage: float = 5.9) -> SensorCalibration:
    """Fit the calibration ``method`` (:data:`METHODS`); see the two functions."""
    if method == "same_force":
        return calibrate_same_force(voltages, actuating_force, mask, clip_voltage=clip_voltage)
    if method == "same_sensor":
        return calibrate_same_sensor(voltages, actuating_force, mask, clip_voltage=clip_voltage)
    raise CalibrationError(f"unknown calibration method {method!r} (one of "
                           f"{', '.join(METHODS)})")


def compare_methods(voltages: ArrayLike, actuating_force: ArrayLike, piston_area: float,
                    mask: ArrayLike | None = None, *,
                    clip_voltage: float = 5.9) -> CalibrationComparison:
    """Fit both methods on the same samples and compare their pressure estimates.

    The differences are evaluated over the samples used for the fit (``mask`` and the usual
    finite/unclipped selection).
    """
    same_force = calibrate_same_force(voltages, actuating_force, mask,
                                      clip_voltage=clip_voltage)
    same_sensor = calibrate_same_sensor(voltages, actuating_force, mask,
                                        clip_voltage=clip_voltage)
    v, _ = _select(voltages, actuating_force, mask, clip_voltage)
    pf = same_force.pressures(v, piston_area)
    ps = same_sensor.pressures(v, piston_area)

    def rms(x: FloatArray) -> float:
        return float(np.sqrt(np.mean(x * x)))

    d = pf.difference - ps.difference
    a, b = pf.difference - pf.difference.mean(), ps.difference - ps.difference.mean()
    denom = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
    corr = float(np.sum(a * b) / denom) if denom > 0.0 else float("nan")
    base = rms(pf.difference)
    return CalibrationComparison(
        same_force, same_sensor, rms(pf.front - ps.front), rms(pf.rear - ps.rear), rms(d),
        float(np.max(np.abs(d))), corr, rms(d) / base if base > 0.0 else float("nan"))


def quasi_static_mask(t: ArrayLike, pressure: ArrayLike, window: float = 0.5,
                      tolerance: float = 0.01, floor: float = 0.5e5) -> BoolArray:
    """Return samples whose pressure stayed within ±tolerance over the last ``window`` s.

    ``t`` [s], ``pressure`` [Pa]; the band is ``tolerance · max(|p|, floor)`` around the
    current pressure (``floor`` [Pa] keeps it from shrinking to 0 near 0 bar). Such samples
    are free of the pack's transient lag, so they suit a calibration against F_act. The
    window is counted in samples of the median sample time (O(n), sliding extrema).
    """
    t = np.asarray(t, dtype=float)
    p = np.asarray(pressure, dtype=float)
    n = t.size
    if n < 2:
        return np.zeros(n, dtype=bool)
    dt = float(np.median(np.diff(t)))
    half = max(1, int(round(window / dt)) // 2) if dt > 0.0 else 1
    size = 2 * half + 1  # trailing window of `size` samples ends at i: centred at i - half
    hi = np.empty(n)
    lo = np.empty(n)
    # scipy.ndimage takes ~0.8 s to import; only calibration needs it (not replay's start-up)
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    hi[half:] = maximum_filter1d(p, size, mode="nearest")[:n - half]
    lo[half:] = minimum_filter1d(p, size, mode="nearest")[:n - half]
    hi[:half], lo[:half] = np.inf, -np.inf
    band = tolerance * np.maximum(np.abs(p), floor)
    full = (t - t[0] >= window) & (np.arange(n) >= size - 1)
    with np.errstate(invalid="ignore"):
        quiet: BoolArray = full & (hi - p <= band) & (p - lo <= band)
        return quiet
