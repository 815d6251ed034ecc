#!/usr/bin/env python3
"""Regenerate (or check) the golden regression data in ``tests/data/golden``.

The golden bags are RigState streams of the simulated rig (truth plant ``rig_truth_elastic``:
``rig_truth`` behind an elastic drivetrain, no bus)
for thesis Table 3 (sequences 1-5 at 10 and 30 rpm) and Table 4 (sequences 1-4), decimated
to 100 Hz. The expected outputs are what ``clutch replay BAG --params flexiforce_8`` gives.

Usage (from the repository root)::

    .venv/bin/python tools/make_golden.py --check      # compare, print a diff, exit 1 if any
    .venv/bin/python tools/make_golden.py --expected   # after a deliberate model change
    .venv/bin/python tools/make_golden.py --bags       # after a deliberate rig-sim change

``--expected`` keeps the bags (the inputs) and recomputes the expected outputs from them;
``--bags`` re-simulates the bags too. Both print what moved before writing. See
``tests/data/golden/README.md`` for when to do which.
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

DEFAULT_ROOT = REPO / "tests" / "data" / "golden"


def _diffs(root: Path, results: dict) -> list[str]:
    from clutch_ros.offline import golden

    if not (root / "expected.json").exists():
        return [f"{root}: no expected.json yet"]
    manifest = golden.load_manifest(root)
    out = []
    for name, (arrays, summary) in results.items():
        if name not in manifest["runs"] or not golden.expected_path(root, name).exists():
            out.append(f"{name}: no stored expected output")
            continue
        stored = golden.load_expected(root, name)
        if not (len(stored["stamp_ns"]) == len(arrays["stamp_ns"])
                and (stored["stamp_ns"] == arrays["stamp_ns"]).all()):
            out.append(f"{name}: sample stamps differ ({len(arrays['stamp_ns'])} samples, "
                       f"stored {len(stored['stamp_ns'])})")
            continue
        t = (arrays["stamp_ns"] - arrays["stamp_ns"][0]) / 1e9
        for field in golden.FIELDS:
            diff = golden.compare_series(name, field, stored[field], arrays[field], t)
            if diff:
                out.append(diff)
        out += golden.compare_summary(name, manifest["runs"][name], summary)
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the tool; return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--check", action="store_true", help="compare only; exit 1 on a diff")
    mode.add_argument("--expected", action="store_true",
                      help="recompute the expected outputs from the existing bags")
    mode.add_argument("--bags", action="store_true",
                      help="re-simulate the bags, then recompute the expected outputs")
    parser.add_argument("--root", type=Path, default=DEFAULT_ROOT,
                        help=f"golden directory (default {DEFAULT_ROOT.relative_to(REPO)})")
    parser.add_argument("--runs", nargs="+", metavar="RUN", help="only these runs")
    args = parser.parse_args(argv)

    import numpy as np
    import scipy

    from clutch_ros.config.params_file import load_flat, load_params
    from clutch_ros.config.presets import preset_path
    from clutch_ros.offline import golden
    from clutch_ros.offline.rig_runs import GOLDEN_RUNS

    names = args.runs or list(GOLDEN_RUNS)
    unknown = sorted(set(names) - set(GOLDEN_RUNS))
    if unknown:
        parser.error(f"unknown run(s) {unknown}; known: {', '.join(GOLDEN_RUNS)}")
    if args.bags:
        for path in golden.generate_bags(args.root, names):
            print(f"wrote {path.relative_to(REPO) if path.is_relative_to(REPO) else path}")
    preset = preset_path(golden.PRESET)
    params = load_params(preset)
    results = {}
    for name in names:
        bag = golden.bag_path(args.root, name)
        if not bag.exists():
            print(f"{bag}: missing; run with --bags", file=sys.stderr)
            return 2
        results[name] = golden.compute_expected(bag, params)
    diffs = _diffs(args.root, results)
    for line in diffs:
        print(line)
    if args.check:
        print(f"{len(names)} runs checked: {'differences above' if diffs else 'no differences'}")
        return 1 if diffs else 0
    meta = {
        "preset": golden.PRESET,
        "plant": golden.PLANT,
        "params": {k: v for k, v in sorted(load_flat(preset).items())},
        "rate_hz": golden.RATE_HZ,
        "runs_spec": {name: list(GOLDEN_RUNS[name]) for name in GOLDEN_RUNS},
        "generated_with": {"python": platform.python_version(), "numpy": np.__version__,
                           "scipy": scipy.__version__, "machine": platform.machine()},
        "tolerances": {k: list(v) for k, v in golden.TOLERANCES.items()},
    }
    if args.runs and (args.root / "expected.json").exists():  # keep the other runs
        old = golden.load_manifest(args.root)["runs"]
        for name, summary in old.items():
            if name not in results:
                results[name] = (golden.load_expected(args.root, name), summary)
    golden.write_expected(args.root, dict(sorted(results.items())), meta)
    total = sum(f.stat().st_size for f in args.root.rglob("*") if f.is_file())
    print(f"wrote expected outputs of {len(names)} runs; golden data: {total / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
