#!/usr/bin/env python3
"""Calibrates drives of the second simulator (independent_sim.py) with
the default method and with batch Gauss-Newton (heading offset
estimated), and tabulates each parameter's error against the truth in
units of the σ the result reports (JSON `sigma`, the σ for the next
drive) and of the within-drive σ (JSON `sigma_within_drive`), coverage
of the 95 % intervals, results accepted beyond 3σ, and RMS errors.

    independent_worlds.py --odocal target/release/odocal --level paper \\
        --seeds 1-20 --length-km 12 --dir /tmp/indep [--csv rows.csv]

Drives already in --dir are reused; so are calibrations (delete the
directory to start over).
"""
import argparse
import csv
import json
import math
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
PARAMS = ["c_e", "c_d", "t_r", "d"]
METHODS = {
    "default": [],
    "batch-gn": ["--method", "batch-gn", "--estimate", "heading-offset"],
}


def seeds(text):
    a, _, b = text.partition("-")
    return range(int(a), int(b or a) + 1)


def run(args, seed, method):
    base = os.path.join(args.dir, f"{args.level}-{seed}")
    if not os.path.exists(base + ".csv"):
        subprocess.run([sys.executable, os.path.join(HERE, "independent_sim.py"), "--seed", str(seed),
                        "--length-km", str(args.length_km), "--level", args.level, "--out", base] + [f"--set={x}" for x in args.set], check=True)
    out = f"{base}.{method}.json"
    if not os.path.exists(out):
        cmd = [args.odocal, "--threads", str(args.threads), "-q", "calibrate", base + ".csv", "--json", out]
        # Exit code 3: a rejected verdict, with its JSON written.
        rc = subprocess.run(cmd + METHODS[method], stdout=subprocess.DEVNULL).returncode
        if rc not in (0, 3):
            sys.exit(f"{' '.join(cmd)}: exit code {rc}")
    truth = json.load(open(base + ".truth.json"))["theta_true"]
    j = json.load(open(out))
    # eiv_result: the default's outcome ("eiv", "batch-gn-fallback"); absent for batch G-N.
    row = dict(level=args.level, seed=seed, method=method, verdict=j["verdict"]["level"],
               result=j.get("eiv_result") or "")
    for p in PARAMS:
        err = j["theta"][p] - truth[p]
        row[f"{p}_err_rel"] = err / truth[p] if p in ("c_e", "t_r") else err
        row[f"{p}_z"] = err / j["sigma"][p] if j["sigma"][p] > 0 else float("nan")
        s_w = j["sigma_within_drive"][p]
        row[f"{p}_z_within"] = err / s_w if s_w > 0 else float("nan")
    return row


def summary(rows):
    lines = ["| level | method | n | accepted | accepted beyond 3σ | 95 % coverage c_e / c_d / t_r / d (σ reported) "
             "| (σ within drive) | RMS c_e % / c_d mm / t_r % / d mm/(m/s²) | mean t_r % (t) |",
             "|---|---|---:|---:|---:|---|---|---|---|"]
    keys = sorted({(r["level"], r["method"]) for r in rows})
    for level, method in keys:
        rs = [r for r in rows if r["level"] == level and r["method"] == method]
        n = len(rs)
        acc = [r for r in rs if r["verdict"] == "accepted"]
        beyond = [r for r in acc if any(abs(r[f"{p}_z"]) > 3 for p in PARAMS)]
        cov = lambda k: " / ".join(  # noqa: E731
            f"{100 * sum(abs(r[f'{p}{k}']) <= 1.96 for r in rs) / n:.0f}" for p in PARAMS)
        scale = {"c_e": 100, "c_d": 1e3, "t_r": 100, "d": 1e3}
        rms = " / ".join(f"{math.sqrt(sum((r[f'{p}_err_rel'] * scale[p]) ** 2 for r in rs) / n):.3f}"
                         for p in PARAMS)
        tr = [r["t_r_err_rel"] * 100 for r in rs]
        mean = sum(tr) / n
        sd = math.sqrt(sum((x - mean) ** 2 for x in tr) / max(n - 1, 1))
        t = mean / (sd / math.sqrt(n)) if sd > 0 else float("nan")
        lines.append(f"| {level} | {method} | {n} | {len(acc)} | {len(beyond)} | {cov('_z')} % | {cov('_z_within')} % "
                     f"| {rms} | {mean:+.3f} ({t:+.1f}) |")
    return "\n".join(lines)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--odocal", required=True, help="the odocal binary")
    p.add_argument("--level", default="paper")
    p.add_argument("--seeds", default="1-20", help="A-B, inclusive")
    p.add_argument("--length-km", type=float, default=12.0)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="passed to independent_sim.py (use a --dir of its own)")
    p.add_argument("--dir", required=True)
    p.add_argument("--csv", help="also write one row per drive and method here")
    a = p.parse_args()
    os.makedirs(a.dir, exist_ok=True)
    rows = [run(a, s, m) for s in seeds(a.seeds) for m in METHODS]
    if a.csv:
        with open(a.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    print(summary(rows))


if __name__ == "__main__":
    main()
