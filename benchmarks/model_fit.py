"""Benchmark of the identification: ``python -m benchmarks.model_fit``.

1. Generates a long 1 kHz run (default one hour) of the simulated rig's truth plant: the
   ``rig_truth`` parameters (:data:`RIG_TRUTH`, the preset's values: coulomb spline law)
   in the model core's :func:`~clutch_ros.model.simulate.simulate`, driven through a seeded
   random series of the thesis's test patterns — steps, incremented steps, 4/12/24 s ramps to
   15–40 bar at 10/30/50 rpm, with 3–8 s rests at 0 bar in between. Around the pack, the rig's
   defaults (``clutch_ros.rig``): a 0.05 s first-order pump lag, a 0.05 s motor speed loop,
   the two-capacity thermal model (lamellas 1500 J/K, 60 W/K to the oil, oil 2e4 J/K, 40 W/K
   to 35 °C) heated by the slip power, and Gaussian sensor noise (torque 1.5 N m, pressure
   0.02 bar, temperature 0.1 °C, speed 0.005 rad/s). (The model core may not import
   ``clutch_ros.rig``, whose package pulls in python-can; a RigPlant run saved with ``np.savez``
   under the keys t, pressure, temperature, slip_speed, torque can be fitted with ``--cache``.)
2. Fits each law (``--laws``, default all four) with the default
   :class:`~clutch_ros.model.identification.FitOptions`, starting from the ``flexiforce_8``
   preset's values, and prints per law the wall time of
   :func:`~clutch_ros.model.identification.fit` (decimation and segment selection included),
   iterations, residual evaluations, fitted samples and segments, the fit RMSE and the fitted
   values next to the truth. ``--max-samples 0`` fits every sample at the fit rate (no
   segment budget, no time guard), after a same-run baseline fit with the default budget.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.signal

from benchmarks.model_step import BENCH_PARAMS
from clutch_ros.model.friction import reference_torque
from clutch_ros.model.identification import FREE_PARAMETERS, FitOptions, FitRun, fit
from clutch_ros.model.params import ClutchParams
from clutch_ros.model.simulate import simulate
from clutch_ros.numeric_env import usable_cores

__all__ = ["RIG_TRUTH", "generate_run", "main"]

BAR = 1e5
#: params/rig_truth.yaml as a dict (the model core reads no YAML; a test checks they agree).
RIG_TRUTH = {
    "clutch.lamella_count": 8, "clutch.effective_radius": 0.045, "clutch.piston_area": 3.75e-3,
    "clutch.lamella_mass": 0.1, "clutch.lamella_stiffness": 4.0e8,
    "clutch.lamella_damping": 5.0e7, "clutch.max_pressure": 5.0e6, "friction.mu_ref": 0.1272,
    "friction.temperature_ref": 35.0, "friction.temperature_slope": -0.0022,
    "friction.pressure_loss_at_ref": 0.05, "friction.pressure_ref": 4.0e6,
    "friction.static_ratio": 1.25, "friction.stribeck_speed": 0.4,
    "friction.sign_speed": 0.01, "friction.mu_min": 0.01, "friction.film_depth": 0.8,
    "friction.film_thinning_time": 0.5, "friction.film_recovery_time": 0.15,
    "thermal.heat_capacity": 1500.0, "thermal.conductance": 60.0,
    "thermal.oil_temperature": 35.0, "spline.law": "coulomb",
    "spline.gain": 0.0, "spline.time_constant": 1.0, "spline.friction_coefficient": 0.05,
    "spline.radius": 0.05, "slip.filter_time_constant": 0.02,
    "drivetrain.stiffness": 0.0, "drivetrain.damping": 0.0,
}
#: Rig defaults used around the pack (clutch_ros.rig: PumpParams, ThermalParams, NoiseParams).
PUMP_TIME_CONSTANT = 0.05  # [s]
MOTOR_TIME_CONSTANT = 0.05  # [s]
THERMAL = {"c_lamella": 1500.0, "g_oil": 60.0, "c_oil": 2.0e4, "g_ambient": 40.0,
           "ambient": 35.0}
NOISE = {"torque": 1.5, "pressure": 2000.0, "temperature": 0.1, "speed": 0.005}


def _schedule(minutes: float, seed: int):
    """Random pressure/slip schedule of ``minutes``: lists of (time, value) breakpoints."""
    rng = np.random.default_rng(seed)
    pt, pv, st, sv = [0.0], [0.0], [0.0], [0.0]
    t = 1.0
    end = minutes * 60.0
    rpm = 10.0
    while t < end - 30.0:
        rpm = float(rng.choice([10.0, 30.0, 50.0], p=[0.5, 0.3, 0.2]))
        w = rpm * 2.0 * np.pi / 60.0
        st += [t, t]
        sv += [sv[-1], w]
        t += 1.0  # the motor settles before the pressure comes (DBP)
        peak = float(rng.uniform(15.0, 40.0)) * BAR
        kind = rng.choice(["step", "inc", "ramp4", "ramp12", "ramp24"])
        if kind == "step":
            hold = float(rng.uniform(3.0, 10.0))
            pt += [t, t, t + hold, t + hold]
            pv += [0.0, peak, peak, 0.0]
            t += hold
        elif kind == "inc":
            for level in (0.25, 0.5, 0.75, 1.0, 0.75, 0.5, 0.25, 0.0):
                pt += [t, t]
                pv += [pv[-1], level * peak]
                t += 3.0 if level != 1.0 else 6.0
            t -= 3.0
        else:
            length = float(kind[4:])
            pt += [t, t + length / 2.0, t + length]
            pv += [0.0, peak, 0.0]
            t += length
        t += float(rng.uniform(3.0, 8.0))
    pt.append(end)
    pv.append(0.0)
    st.append(end)
    sv.append(sv[-1])
    return pt, pv, st, sv


def _lag(u: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """First-order lag, exact ZOH, starting at rest at u[0]."""
    a = math.exp(-dt / tau)
    y, _ = scipy.signal.lfilter([1.0 - a], [1.0, -a], u, zi=[a * u[0]])
    return y


def _thermal(power: np.ndarray, dt: float) -> np.ndarray:
    """Lamella temperature [°C] of the two-capacity model heated by ``power`` [W] from rest.

    Lamellas and oil start at the conditioning setpoint (35 °C, the thesis's start).
    """
    th = THERMAL
    a = np.array([[-th["g_oil"] / th["c_lamella"], th["g_oil"] / th["c_lamella"]],
                  [th["g_oil"] / th["c_oil"], -(th["g_oil"] + th["g_ambient"]) / th["c_oil"]]])
    b = np.array([[1.0 / th["c_lamella"]], [0.0]])
    aug = np.zeros((3, 3))
    aug[:2, :2], aug[:2, 2:] = a * dt, b * dt
    e = scipy.linalg.expm(aug)
    phi, gam = e[:2, :2], e[:2, 2:]
    num, den = scipy.signal.ss2tf(phi, gam, np.array([[1.0, 0.0]]), np.zeros((1, 1)))
    return th["ambient"] + scipy.signal.lfilter(num[0], den, power)


def generate_run(minutes: float = 60.0, seed: int = 7, dt: float = 1e-3,
                 truth: ClutchParams | None = None) -> dict:
    """Simulate the truth plant for ``minutes`` at ``1/dt`` Hz (module docstring).

    ``truth``: the pack parameters (default :data:`RIG_TRUTH`). Returns arrays ``t`` [s],
    ``pressure`` [Pa], ``temperature`` [°C], ``slip_speed`` [rad/s], ``torque`` [N m]
    (measured: with noise) and ``seconds`` (generation time).
    """
    start = time.perf_counter()
    truth = ClutchParams.from_flat(RIG_TRUTH) if truth is None else truth
    rng = np.random.default_rng(seed)
    pt, pv, st, sv = _schedule(minutes, seed)
    n = int(round(minutes * 60.0 / dt)) + 1
    t = np.arange(n) * dt
    request = np.interp(t - dt, pt, pv)  # the command held over the step ending at t
    slip_cmd = np.interp(t - dt, st, sv)
    pressure = np.maximum(_lag(request, dt, PUMP_TIME_CONSTANT), 0.0)
    slip = _lag(slip_cmd, dt, MOTOR_TIME_CONSTANT)
    # heating by the steady-state slip power (the pack's lag changes it by well under 1 %)
    power = np.abs(reference_torque(truth, pressure, 35.0, slip) * slip)
    temp = _thermal(power, dt)
    temp = _thermal(np.abs(reference_torque(truth, pressure, temp, slip) * slip), dt)
    sim = simulate(truth, t, pressure, slip, temp)
    out = {
        "t": t,
        "pressure": np.maximum(pressure + NOISE["pressure"] * rng.standard_normal(n), 0.0),
        "temperature": temp + NOISE["temperature"] * rng.standard_normal(n),
        "slip_speed": slip + NOISE["speed"] * rng.standard_normal(n),
        "torque": sim.torque + NOISE["torque"] * rng.standard_normal(n),
    }
    out["seconds"] = time.perf_counter() - start
    return out


def _out(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def main(argv=None) -> int:
    """Generate (or load) the run, fit every law, print the figures."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.model_fit",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="run length (default 60)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--laws", default="none,ff_t,ff_v,coulomb",
                        help="comma-separated laws to fit (default: all)")
    parser.add_argument("--cache", metavar="FILE.npz", help="load the run from / save it to")
    parser.add_argument("--max-samples", type=int, default=None, metavar="N",
                        help="segment budget (FitOptions.max_samples; 0: every sample at the "
                             "fit rate); each law is then fitted with the default budget "
                             "first, as the same-run baseline")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args(argv)
    cache = Path(args.cache) if args.cache else None
    if cache is not None and cache.is_file():
        data = dict(np.load(cache))
        data["seconds"] = float("nan")
        how = f"loaded from {cache}"
    else:
        sys.stderr.write(f"generating a {args.minutes:g} min 1 kHz run of the truth plant...\n")
        data = generate_run(args.minutes, args.seed)
        how = f"generated in {data['seconds']:.1f} s"
        if cache is not None:
            np.savez(cache, **{k: v for k, v in data.items() if k != "seconds"})
    n = data["t"].size
    duration = float(data["t"][-1] - data["t"][0])
    _out(f"run: {n:,} samples, {duration / 60.0:.1f} min at "
          f"{1.0 / float(np.median(np.diff(data['t']))):.0f} Hz, lamella temperature "
          f"{data['temperature'].min():.0f}..{data['temperature'].max():.0f} degC ({how})")
    run = FitRun(data["t"], data["pressure"], data["temperature"], data["slip_speed"],
                 data["torque"], name="bench")
    base = ClutchParams.from_flat(BENCH_PARAMS)
    truth = RIG_TRUTH
    results = []
    for law in [s.strip() for s in args.laws.split(",") if s.strip()]:
        if args.max_samples is not None:
            ref = fit([run], law, base, options=FitOptions(workers=usable_cores()))
            _out(f"{law:8s} baseline, default budget: fit {ref.seconds:6.1f} s  "
                 f"({ref.evaluations} evaluations, {ref.samples:,} samples), RMSE "
                 f"{ref.rmse:.2f} N m")
        # the Jacobian's columns in one thread per usable core, as `clutch fit` runs them
        options = FitOptions(max_samples=args.max_samples, max_seconds=None,
                             workers=usable_cores()) \
            if args.max_samples is not None else FitOptions(workers=usable_cores())
        result = fit([run], law, base, options=options)
        results.append(result)
        _out(f"{law:8s} fit {result.seconds:6.1f} s  ({result.iterations} iterations, "
              f"{result.evaluations} evaluations, {result.samples:,} samples in "
              f"{result.segments} segments at {result.fit_rate_hz:g} Hz), RMSE "
              f"{result.rmse:.2f} N m")
        for key in FREE_PARAMETERS[law]:
            if key in result.values:
                same = not key.startswith("spline.") or law == truth["spline.law"]
                ref = f"truth {truth[key]:.6g}" if same else \
                    f"(no {law} in the {truth['spline.law']} truth)"
                _out(f"    {key:30s} {result.values[key]:12.6g} ± "
                     f"{result.stderr[key]:.2g}   {ref}")
    worst = max(r.seconds for r in results) if results else float("nan")
    target = "< 30 s with every sample (issue 17)" if args.max_samples == 0 else \
        "< 60 s for a one-hour 1 kHz run"
    _out(f"slowest fit: {worst:.1f} s (target {target})")
    if args.json:
        _out(json.dumps({"samples": n, "duration_s": duration,
                          "generation_s": (None if math.isnan(data["seconds"])
                                           else data["seconds"]),
                          "fits": [r.to_dict() for r in results]}, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
