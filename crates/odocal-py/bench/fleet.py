"""Ray fleet wall time against serial calls: 1, 2, 4, 8 simulated drives.

    python crates/odocal-py/bench/fleet.py [--length-km 6] [--num-cpus 2] [--counts 1,2,4,8]

Serial: the drives one after the other in this process (odocal on all
cores). Ray: examples/fleet_ray.py's calibrate_fleet on a local Ray of
--num-cpus CPUs, one CPU (one odocal thread) per task. Ray start-up is
timed separately. Not a test: run it by hand on a quiet machine.
"""

import argparse
import importlib.util
import os
import tempfile
import time
from pathlib import Path

import odocal

REPO = Path(__file__).resolve().parents[3]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--length-km", type=float, default=6.0)
    ap.add_argument("--num-cpus", type=int, default=2)
    ap.add_argument("--counts", default="1,2,4,8")
    ap.add_argument("--method", default="three-step")
    a = ap.parse_args()
    counts = [int(c) for c in a.counts.split(",")]
    spec = importlib.util.spec_from_file_location("fleet_ray", REPO / "examples" / "fleet_ray.py")
    fleet = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fleet)

    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for seed in range(1, max(counts) + 1):
            p = Path(tmp) / f"car{seed}.csv"
            odocal.simulate(seed=seed, length_km=a.length_km).to_csv(p)
            paths.append(p)
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        t0 = time.perf_counter()
        fleet.init_ray(num_cpus=a.num_cpus)
        print(f"ray.init: {time.perf_counter() - t0:.2f} s")
        fleet.calibrate_fleet(paths[:1], a.method)  # warm the workers up
        print(f"{'drives':>6} {'serial s':>9} {'ray s':>8} {'ray/serial':>10}")
        for n in counts:
            t0 = time.perf_counter()
            serial = fleet.calibrate_serial(paths[:n], a.method)
            ts = time.perf_counter() - t0
            t0 = time.perf_counter()
            rows = fleet.calibrate_fleet(paths[:n], a.method)
            tr = time.perf_counter() - t0
            assert [r["c_e"] for r in rows] == [r["c_e"] for r in serial]
            print(f"{n:6d} {ts:9.2f} {tr:8.2f} {tr / ts:10.2f}")


if __name__ == "__main__":
    main()
