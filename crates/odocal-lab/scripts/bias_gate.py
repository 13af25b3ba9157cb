#!/usr/bin/env python3
"""Would a significance gate tell when to correct t_r and d?

Reads the `results.csv` of `random_worlds --methods eiv --correct-bias-of
c_e,c_d,t_r,d` runs (one directory each) and recomputes each fit as if t_r
and d had been corrected only where the bootstrap's bias exceeds z times
its Monte Carlo standard error (c_e and c_d corrected as the default does).
A fit's uncorrected value is the corrected one plus the subtracted bias
(`bias` in `eiv_extra`), and its uncorrected σ² the corrected one minus the
correction's Monte Carlo variance (`bias_mc`): the bootstrap is the same
whichever parameters it corrects, so this is exact for θ and σ (the
verdict is taken from the run).

    python3 bias_gate.py DIR [DIR ...]

Prints, per directory and gate, t_r's and d's RMS error over the own
estimates (the fits that did not fall back), how many of them the gate
corrected, and the results accepted beyond 3 σ.
"""
import csv
import math
import sys

PARAMS = ["c_e_pct", "c_d_mm", "t_r_pct", "d_mm_per_m_per_s2"]
GATES = [("never (default)", math.inf), ("z = 3", 3.0), ("z = 2", 2.0), ("z = 1.41", math.sqrt(2.0)),
         ("always", 0.0)]


def eiv_extra(row):
    return dict(kv.split("=", 1) for kv in row["eiv_extra"].split(";") if "=" in kv)


def fits(directory):
    out = []
    with open(f"{directory}/results.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["method"] != "eiv" or row["status"] != "ok":
                continue
            err = [float(row["err_" + p]) for p in PARAMS]
            sigma = [float(row["sigma_" + p]) for p in PARAMS]
            fell_back = row["fallback"] == "true"
            bias, mc = [0.0] * 4, [0.0] * 4
            if not fell_back:
                extra = eiv_extra(row)
                b = [float(x) for x in extra["bias"].split()]
                m = [float(x) for x in extra["bias_mc"].split()]
                uncorrected = [float(x) for x in extra["uncorrected"].split()]
                # SI units to the error columns' (% of the truth, mm).
                scale = [0.0, 1000.0, 0.0, 1000.0]
                for i in (0, 2):
                    truth = (uncorrected[i] - b[i]) / (1.0 + err[i] / 100.0)
                    scale[i] = 100.0 / truth
                bias = [b[i] * scale[i] for i in range(4)]
                mc = [m[i] * scale[i] for i in range(4)]
            out.append(dict(world=row["world_seed"], accepted=row["verdict"] == "accepted",
                            fell_back=fell_back, err=err, sigma=sigma, bias=bias, mc=mc))
    return out


def gated(fit, z):
    """The fit's errors and σ with t_r and d corrected where |bias| > z·mc."""
    err, sigma, corrected = list(fit["err"]), list(fit["sigma"]), [False] * 4
    if fit["fell_back"]:
        return err, sigma, corrected
    for i in (2, 3):
        if fit["mc"][i] > 0.0 and abs(fit["bias"][i]) > z * fit["mc"][i]:
            corrected[i] = True
            continue
        err[i] += fit["bias"][i]
        if fit["mc"][i] > 0.0:
            sigma[i] = math.sqrt(max(sigma[i] ** 2 - fit["mc"][i] ** 2, 0.0))
    return err, sigma, corrected


def main(directories):
    print("| worlds | gate | own | t_r % RMS | t_r corrected | d RMS | d corrected | accepted beyond 3 σ |")
    print("|---|---|---:|---:|---:|---:|---:|---|")
    for d in directories:
        all_fits = fits(d)
        own = [f for f in all_fits if not f["fell_back"]]
        for name, z in GATES:
            rows = [gated(f, z) for f in own]
            rms = [math.sqrt(sum(r[0][i] ** 2 for r in rows) / len(rows)) for i in (2, 3)]
            n = [sum(r[2][i] for r in rows) for i in (2, 3)]
            beyond = [f["world"] for f in all_fits
                      if f["accepted"] and any(abs(e) > 3 * s for e, s in zip(*gated(f, z)[:2]))]
            print(f"| {d} | {name} | {len(own)} | {rms[0]:.4f} | {n[0]} | {rms[1]:.4f} | {n[1]} | "
                  f"{len(beyond)} ({' '.join(beyond)}) |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
