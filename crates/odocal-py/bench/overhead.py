"""Binding overhead: wall time of odocal.calibrate from Python against the
library's own total (report timing_s.total) on the same drive.

    python crates/odocal-py/bench/overhead.py [--length-km 24] [--repeats 5]

Not a test: run it by hand on a quiet machine (numbers in the report and
docs/guide.md, "A fleet on Ray").
"""

import argparse
import statistics
import time

import odocal


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--length-km", type=float, default=24.0)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    sim = odocal.simulate(seed=1, length_km=a.length_km)
    # The same samples without the simulator's truth, so that calibrate does
    # not also validate θ_true (the CLI's "truth" entry): the library's work
    # is then exactly the calibration.
    cols = dict(zip(sim.columns, sim.to_numpy().T))
    drive = odocal.Drive.from_arrays(
        cols["t"], cols["px"], cols["py"], cols["psi"], cols["n_rl"], cols["n_rr"], cols["a_y"],
        beta=cols["beta"], sample_time_s=sim.sample_time_s,
    )
    for method in ("batch-gn", "three-step"):
        walls, libs = [], []
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            r = odocal.calibrate(drive, method)
            walls.append(time.perf_counter() - t0)
            libs.append(r.to_dict()["timing_s"]["total"])
        w, lib = statistics.median(walls), statistics.median(libs)
        print(f"{method:10s} {a.length_km:g} km: python {w * 1e3:9.2f} ms, library {lib * 1e3:9.2f} ms, "
              f"overhead {(w - lib) * 1e3:7.2f} ms, ratio {w / lib:.4f} (median of {a.repeats})")


if __name__ == "__main__":
    main()
