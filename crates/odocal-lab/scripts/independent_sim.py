#!/usr/bin/env python3
"""A second simulator of the drive model, written from docs/method.md
(the model's equations and the simulator's description) without
odocal's simulator code, so that odocal can be judged on drives it was not
shaped on.

It differs from `odocal simulate` where a real car would: the vehicle
moves in continuous time (integrated at `--substeps` steps per sample
from a path of clothoid-smoothed curvature, not by the model's discrete
step); the sideslip comes from a single-track model and the yaw rate is
the heading's derivative (so it differs from v·κ while β changes); a_y is
v·χ' with χ the direction of travel; the wheel readings are encoder
counts over each sample. Its wheel noise is dominated by slow
common-mode scale variation and slip with longitudinal acceleration, not
by white noise; the reference carries a constant heading offset (its
own, per drive), slow Gauss-Markov drift and white noise.

Writes DRIVE.csv (the columns of docs/reference.md's drive CSV plus the
truth) and DRIVE.truth.json (θ and every setting). numpy only.

    independent_sim.py --seed 7 --length-km 12 --level paper --out /tmp/x
"""
import argparse
import json

import numpy as np

LEVELS = {
    # relative σ and time constants of the wheel noise, slip per m/s²,
    # reference noise. "heavy" is 2.5 × "paper" in every wheel source.
    "none": dict(common=0.0, tau_common=20.0, wheel=0.0, tau_wheel=5.0, white=0.0, slip=0.0,
                 ticks=0, pos_white=0.0, pos_drift=0.0, head_white=0.0, head_drift=0.0,
                 tau_drift=200.0, head_offset=0.0, ay_sigma=0.0, beta_sigma=0.0, dwell=1.0),
    "paper": dict(common=0.003, tau_common=20.0, wheel=0.0005, tau_wheel=5.0, white=0.002,
                  slip=0.003, ticks=500, pos_white=0.02, pos_drift=0.2, head_white=3e-4,
                  head_drift=1e-3, tau_drift=200.0, head_offset=0.02, ay_sigma=0.05,
                  beta_sigma=1e-3, dwell=1.0),
}
LEVELS["heavy"] = dict(LEVELS["paper"], common=0.0075, wheel=0.00125, white=0.005, slip=0.0075)
LEVELS["wheels-only"] = dict(LEVELS["paper"], pos_white=0.0, pos_drift=0.0, head_white=0.0,
                             head_drift=0.0, head_offset=0.0, ay_sigma=0.0, beta_sigma=0.0)


def curvature_profile(rng, length_m, ds):
    """Curvature κ(s) of a city/suburb route: straights, bends, 90° turns,
    roundabouts; each piece with a target speed; stops at some ends."""
    kappa, vmax, stops = [], [], []
    s = 0.0
    while s < length_m:
        kind = rng.choice(["straight", "bend", "turn", "roundabout"], p=[0.45, 0.3, 0.15, 0.1])
        sign = rng.choice([-1.0, 1.0])
        if kind == "straight":
            n = int(rng.uniform(60.0, 500.0) / ds)
            k, v = 0.0, rng.uniform(9.0, 22.0)
        elif kind == "bend":
            r = rng.uniform(25.0, 400.0)
            n = int(r * np.radians(rng.uniform(15.0, 120.0)) / ds)
            k, v = sign / r, rng.uniform(9.0, 22.0)
        elif kind == "turn":
            r = rng.uniform(7.0, 14.0)
            n = int(r * np.pi / 2 / ds)
            k, v = sign / r, 6.0
        else:
            r = rng.uniform(12.0, 22.0)
            n = int(r * np.radians(rng.uniform(90.0, 300.0)) / ds)
            k, v = 1.0 / r, 7.0  # counter-clockwise, as in right-hand traffic
        kappa += [k] * n
        vmax += [v] * n
        s += n * ds
        if rng.uniform() < 0.12:
            stops.append(len(kappa) - 1)
    kappa = np.array(kappa)
    # Clothoid transitions: κ is smoothed over 12 m.
    w = max(1, int(12.0 / ds))
    kappa = np.convolve(np.pad(kappa, (w, w), mode="edge"), np.ones(w) / w, mode="same")[w:-w]
    return kappa, np.array(vmax), stops


def speed_profile(kappa, vmax, stops, ds, a_lat=2.5, a_acc=1.3, a_dec=1.8):
    """Speed over arc length within the lateral and longitudinal limits,
    0.3 m/s at the stops (the dwell is added in time, creeping)."""
    v = np.minimum(vmax, np.sqrt(a_lat / np.maximum(np.abs(kappa), 1e-9)))
    v[stops] = 0.3
    v[0] = v[-1] = 0.3
    for i in range(1, len(v)):
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * a_acc * ds))
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * a_dec * ds))
    return v


def gauss_markov(rng, n, dt, sigma, tau):
    if sigma == 0.0:
        return np.zeros(n)
    a = np.exp(-dt / tau)
    w = rng.normal(0.0, sigma * np.sqrt(1 - a * a), n)
    x = np.empty(n)
    x[0] = rng.normal(0.0, sigma)
    for i in range(1, n):
        x[i] = a * x[i - 1] + w[i]
    return x


def simulate(seed, length_km, level, substeps, ts=0.025, overrides=()):
    rng = np.random.default_rng(seed)
    L = dict(LEVELS[level])
    for item in overrides:
        key, _, value = item.partition("=")
        if key not in L:
            raise SystemExit(f"--set {item}: no setting '{key}' (settings: {', '.join(L)})")
        L[key] = float(value)
    theta = dict(c_e=rng.uniform(1.90, 2.05), c_d=rng.uniform(-3e-3, 3e-3),
                 t_r=rng.uniform(1.45, 1.65), d=rng.uniform(3e-4, 1.2e-3))
    ds = 0.1
    kappa, vmax, stops = curvature_profile(rng, length_km * 1000.0, ds)
    v_s = speed_profile(kappa, vmax, stops, ds)
    # Time along the path (trapezoid of ds/v), plus a dwell at each stop,
    # spent on the path's next 0.1 m: the car creeps up (1-5 cm/s), as in
    # a queue, and does not stand.
    dt_s = 2 * ds / (v_s[1:] + v_s[:-1])
    dwell = np.zeros_like(dt_s)
    for k in stops:
        if k < len(dwell):
            # `dwell` scales the 2-8 s (0: the car passes its stops at 0.3 m/s).
            dwell[k] = rng.uniform(2.0, 8.0) * L["dwell"]
    t_s_path = np.concatenate([[0.0], np.cumsum(dt_s + dwell)])
    s_path = np.arange(len(kappa)) * ds
    # The fine time grid, and the arc length along it.
    h = ts / substeps
    n_out = int(t_s_path[-1] / ts) - 1
    tf = np.arange(n_out * substeps + 1) * h
    sf = np.interp(tf, t_s_path, s_path)
    v = np.gradient(sf, h)
    a_x = np.gradient(v, h)
    kf = np.interp(sf, s_path, kappa)
    # Direction of travel χ (∫κ ds), position by the midpoint rule on the fine grid.
    chi = np.concatenate([[0.0], np.cumsum(0.5 * (kf[1:] + kf[:-1]) * np.diff(sf))])
    chi_mid = 0.5 * (chi[1:] + chi[:-1])
    px = np.concatenate([[0.0], np.cumsum(np.cos(chi_mid) * np.diff(sf))])
    py = np.concatenate([[0.0], np.cumsum(np.sin(chi_mid) * np.diff(sf))])
    # Single-track sideslip at the rear axle: β = κ (l_r − K v²).
    beta = kf * (1.3 - 0.004 * v * v)
    psi = chi - beta
    omega = np.gradient(psi, h)
    a_y = v * np.gradient(chi, h)
    c_rl = theta["c_e"] + theta["c_d"] / 2 + theta["d"] * a_y
    c_rr = theta["c_e"] - theta["c_d"] / 2 - theta["d"] * a_y
    n_rl = (v - omega * theta["t_r"] / 2) / c_rl
    n_rr = (v + omega * theta["t_r"] / 2) / c_rr
    # Slip and wheel-scale noise act on the fine grid; the wheels' counted
    # rotations are integrated over it.
    common = gauss_markov(rng, len(tf), h, L["common"], L["tau_common"])
    scale_l = 1 + common + gauss_markov(rng, len(tf), h, L["wheel"], L["tau_wheel"]) + L["slip"] * a_x
    scale_r = 1 + common + gauss_markov(rng, len(tf), h, L["wheel"], L["tau_wheel"]) + L["slip"] * a_x

    def per_sample(x):
        # Mean over each output interval (trapezoid on the fine grid).
        seg = 0.5 * (x[1:] + x[:-1])
        return seg.reshape(n_out, substeps).mean(axis=1)

    def counted(n, scale):
        # Rotations over each sample with a white relative error (the
        # sampling instants' jitter), accumulated and counted in whole ticks
        # (a random phase), so the readings lie on the encoder's lattice.
        y = n * scale
        rot = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * h)])
        inc = np.diff(rot[::substeps])
        inc = inc * (1 + rng.normal(0.0, 1.0, n_out) * L["white"])
        at = np.concatenate([[0.0], np.cumsum(inc)])
        if L["ticks"]:
            at = np.floor(at * L["ticks"] + rng.uniform()) / L["ticks"]
        return np.diff(at) / ts

    out = {}
    idx = np.arange(n_out) * substeps
    out["t"] = idx * h
    drift = lambda sig: gauss_markov(rng, n_out, ts, sig, L["tau_drift"])  # noqa: E731
    out["px"] = px[idx] + drift(L["pos_drift"]) + rng.normal(0.0, L["pos_white"] or 1e-12, n_out)
    out["py"] = py[idx] + drift(L["pos_drift"]) + rng.normal(0.0, L["pos_white"] or 1e-12, n_out)
    offset = rng.uniform(-1.0, 1.0) * L["head_offset"]
    out["psi"] = psi[idx] + offset + drift(L["head_drift"]) + rng.normal(0.0, L["head_white"] or 1e-12, n_out)
    out["n_rl"] = counted(n_rl, scale_l)
    out["n_rr"] = counted(n_rr, scale_r)
    b_true, a_true = per_sample(beta), per_sample(a_y)
    out["beta"] = b_true + rng.normal(0.0, L["beta_sigma"] or 1e-12, n_out) + 0.5 * L["beta_sigma"]
    out["a_y"] = a_true + rng.normal(0.0, L["ay_sigma"] or 1e-12, n_out) + 0.4 * L["ay_sigma"]
    out["px_true"], out["py_true"], out["psi_true"] = px[idx], py[idx], psi[idx]
    out["n_rl_true"], out["n_rr_true"] = per_sample(n_rl), per_sample(n_rr)
    out["beta_true"], out["a_y_true"] = b_true, a_true
    info = dict(seed=seed, length_km=length_km, level=level, substeps=substeps, sample_time_s=ts,
                theta_true=theta, heading_offset_rad=offset, settings=L,
                duration_s=float(out["t"][-1]), samples=int(n_out))
    return out, info


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--length-km", type=float, default=12.0)
    p.add_argument("--level", choices=sorted(LEVELS), default="paper")
    p.add_argument("--substeps", type=int, default=10)
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one setting of the level (repeatable), e.g. ticks=0")
    p.add_argument("--out", required=True, help="path without extension: writes OUT.csv and OUT.truth.json")
    a = p.parse_args()
    out, info = simulate(a.seed, a.length_km, a.level, a.substeps, overrides=a.set)
    cols = list(out)
    data = np.column_stack([out[c] for c in cols])
    np.savetxt(a.out + ".csv", data, delimiter=",", header=",".join(cols), comments="", fmt="%.9g")
    with open(a.out + ".truth.json", "w") as f:
        json.dump(info, f, indent=1)


if __name__ == "__main__":
    main()
