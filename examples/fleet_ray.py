#!/usr/bin/env python3
"""Calibrate a fleet's drives on Ray: one Ray task per drive, one table out.

    python examples/fleet_ray.py DRIVES_DIR_OR_FILES... --out fleet.csv
    python examples/fleet_ray.py drives/ --out fleet.parquet --address auto --cpus-per-task 2
    python examples/fleet_ray.py drives/ --out fleet.csv --params-dir params/   # + one ROS 2 parameter file per drive

Every input is a drive (a canonical CSV or a `.toml` manifest) or a
directory of them. Each drive is calibrated by `odocal.calibrate` in its own
Ray task, on the node where the task runs (the task receives the path, so
the drives must be readable there: a shared file system or object store);
the rows come back in input order and are written as CSV or, for a
`.parquet` path, Parquet (needs pyarrow). A drive that fails (a bad drive,
or a bad value of an `-o` option) gives a row with `status = error` and the
library's message instead of stopping the run; an `-o` name that
`odocal.calibrate` does not take stops it before any drive is calibrated
(exit 2, as argparse's usage errors).
The σ columns are the σ that stands for each result (the verdict's, as
`--params-out` and the JSON `sigma` give; `sigma_source` names it; empty for
a held parameter). With `--params-dir DIR` each calibrated drive's parameter
file is written as DIR/<drive name>.yaml (θ, σ, verdict, provenance: what
`odocal calibrate --params-out` writes), so a deployment can take the files
whose verdict is `accepted`.

Without `--address` a local Ray is started (usage statistics and the
dashboard off: it needs no network); with `--address auto` or
`--address ray://HOST:10001` the script joins an existing cluster. See
docs/guide.md, "A fleet on Ray".
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any, Iterable, Optional

#: Columns of the fleet table, in order.
FIELDS = [
    "drive",
    "status",
    "method",
    "samples",
    "distance_km",
    "c_e",
    "c_d",
    "t_r",
    "d",
    "sigma_c_e",
    "sigma_c_d",
    "sigma_t_r",
    "sigma_d",
    "sigma_source",
    "verdict",
    "mean_position_error_m",
    "initial_mean_position_error_m",
    "validation_segments",
    "warnings",
    "params_file",
    "error",
    "wall_s",
    "node",
]

DRIVE_SUFFIXES = (".csv", ".toml")


def find_drives(inputs: Iterable[str | os.PathLike]) -> list[Path]:
    """The drives named by `inputs`: files as given, directories searched
    (not recursively) for `*.csv` and `*.toml`, sorted by name."""
    found: list[Path] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            found.extend(sorted(q for q in p.iterdir() if q.suffix.lower() in DRIVE_SUFFIXES and q.is_file()))
        elif p.exists():
            found.append(p)
        else:
            raise FileNotFoundError(f"{p}: no such drive or directory")
    return found


def _verdict_text(verdict: Any) -> str:
    if verdict is None:
        return ""
    if isinstance(verdict, str):
        return verdict
    if isinstance(verdict, dict):
        for key in ("status", "verdict", "level"):
            if isinstance(verdict.get(key), str):
                return verdict[key]
    return json.dumps(verdict, sort_keys=True)


def calibrate_one(path: str, method: str = "eiv", options: Optional[dict] = None,
                  threads: Optional[int] = None, params_dir: Optional[str] = None) -> dict:
    """Calibrates one drive and returns its table row (never raises for a
    bad drive: the row says `status = error`); with `params_dir`, also
    writes the drive's parameter file there (`<drive stem>.yaml`). Runs
    inside a Ray task, or directly for a serial run."""
    import odocal

    row: dict[str, Any] = {k: "" for k in FIELDS}
    row.update(drive=str(path), method=method, node=socket.gethostname())
    t0 = time.perf_counter()
    try:
        drive = odocal.Drive.load(path)
        row.update(samples=len(drive), distance_km=drive.distance_m / 1e3)
        report = odocal.calibrate(drive, method, threads=threads, **(options or {}))
        sigma = report.result_sigma or {}
        row.update(
            status="ok",
            **report.theta,
            **{f"sigma_{k}": "" if sigma.get(k) is None else sigma[k] for k in odocal.THETA_NAMES},
            sigma_source=sigma.get("source", ""),
            verdict=_verdict_text(report.verdict),
            mean_position_error_m=report.mean_position_error_m,
            initial_mean_position_error_m=report.initial["mean_position_error_m"],
            validation_segments=report.validation["segments"],
            warnings=len(report.warnings),
        )
        if params_dir is not None:
            out = Path(params_dir) / (Path(path).stem + ".yaml")
            report.write_params(out, input=str(path))
            row["params_file"] = str(out)
    except (odocal.OdocalError, OSError) as e:
        row.update(status="error", error=str(e))
    row["wall_s"] = time.perf_counter() - t0
    return row


def calibrate_serial(paths: Iterable[str | os.PathLike], method: str = "eiv",
                     options: Optional[dict] = None, threads: Optional[int] = None,
                     params_dir: Optional[str | os.PathLike] = None) -> list[dict]:
    """The same rows as `calibrate_fleet`, one drive after the other in this process."""
    pdir = None if params_dir is None else str(params_dir)
    return [calibrate_one(str(p), method, options, threads, pdir) for p in paths]


def init_ray(address: Optional[str] = None, num_cpus: Optional[int] = None, **kwargs: Any) -> None:
    """Starts a local Ray (address None) or joins a cluster. Usage statistics
    and the dashboard are off: a local Ray then needs no network."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    import ray

    if ray.is_initialized():
        return
    if address is None:
        ray.init(num_cpus=num_cpus, include_dashboard=False, **kwargs)
    else:
        ray.init(address=address, **kwargs)


def calibrate_fleet(paths: Iterable[str | os.PathLike], method: str = "eiv",
                    options: Optional[dict] = None, cpus_per_task: int = 1,
                    params_dir: Optional[str | os.PathLike] = None) -> list[dict]:
    """Calibrates every drive in its own Ray task (Ray must be initialised,
    see `init_ray`) and returns the rows in input order.

    Each task reserves `cpus_per_task` CPUs and runs odocal on that many
    threads, so the tasks of one node do not oversubscribe its cores; the
    numbers do not depend on it (odocal is thread-count independent). The
    tasks write the parameter files into `params_dir` themselves, so on a
    cluster it must be a shared directory, like the drives."""
    import ray

    pdir = None if params_dir is None else str(params_dir)
    task = ray.remote(num_cpus=cpus_per_task)(calibrate_one)
    refs = [task.remote(str(p), method, options, cpus_per_task, pdir) for p in paths]
    return ray.get(refs)


def write_table(rows: list[dict], out: str | os.PathLike) -> None:
    """Writes the rows as CSV, or as Parquet for a `.parquet` path (pyarrow)."""
    out = Path(out)
    # Written beside the target and renamed into place: an interrupted run
    # leaves the previous table or none, never a part of one.
    tmp = out.with_name(f".{out.name}.tmp")
    if out.suffix.lower() == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        cols = {k: [r.get(k) if r.get(k) != "" else None for r in rows] for k in FIELDS}
        pq.write_table(pa.table(cols), tmp)
        os.replace(tmp, out)
        return
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS)
        w.writeheader()
        w.writerows(rows)
    os.replace(tmp, out)


def _option(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"'{text}': give KEY=VALUE, e.g. batches=20")
    try:
        return key.strip(), json.loads(value)
    except json.JSONDecodeError:
        return key.strip(), value


#: Options with a flag of their own: `-o` would give them twice.
OWN_FLAGS = {"method": "--method", "threads": "--cpus-per-task", "progress": None}


def check_options(options: dict) -> Optional[str]:
    """What is wrong with the `-o` options' names (None: nothing), checked
    before any drive is calibrated: an unknown name would fail every drive
    alike. Their values are checked per drive (an error row)."""
    import odocal

    for key in options:
        if key in OWN_FLAGS:
            flag = OWN_FLAGS[key]
            return f"-o {key}: " + (f"give it as {flag}" if flag else "not an option of this script")
        if key not in odocal.CALIBRATE_OPTIONS:
            return f"-o {key}: not an option of odocal.calibrate; options: {', '.join(odocal.CALIBRATE_OPTIONS)}"
    return None


def main(argv: Optional[list[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="+", help="drives (CSV or .toml manifest) or directories of them")
    ap.add_argument("--out", required=True, help="the table: .csv or .parquet")
    ap.add_argument("--method", default="eiv", help="eiv (default), three-step or batch-gn")
    ap.add_argument("--option", "-o", action="append", type=_option, default=[], metavar="KEY=VALUE",
                    help="an odocal.calibrate option, named like the CLI flag (batches=20, fix=c_d,t_r,d, ...)")
    ap.add_argument("--address", help="join this Ray cluster ('auto', 'ray://host:10001'); default: a local Ray")
    ap.add_argument("--num-cpus", type=int, help="CPUs of the local Ray (default: all)")
    ap.add_argument("--cpus-per-task", type=int, default=1, help="CPUs (odocal threads) per drive, default 1")
    ap.add_argument("--serial", action="store_true", help="no Ray: calibrate one drive after the other here")
    ap.add_argument("--params-dir", help="also write each drive's ROS 2 parameter file here (<drive name>.yaml)")
    a = ap.parse_args(argv)
    options = dict(a.option)
    problem = check_options(options)
    if problem:
        ap.error(problem)

    try:
        paths = find_drives(a.inputs)
    except FileNotFoundError as e:
        ap.error(str(e))
    out = Path(a.out)
    same = [p for p in paths if out.exists() and os.path.samefile(out, p)]
    if same:
        ap.error(f"--out {a.out} is also the drive {same[0]}: writing the table would destroy it; give --out "
                 "another path")
    if not paths:
        print("no drives found (looked for *.csv and *.toml)", file=sys.stderr)
        return 1
    stems = [p.stem for p in paths]
    if a.params_dir is not None:
        twice = sorted({s for s in stems if stems.count(s) > 1})
        if twice:
            print(f"--params-dir: drives share a name ({', '.join(twice)}): their parameter files would collide",
                  file=sys.stderr)
            return 1
        Path(a.params_dir).mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if a.serial:
        rows = calibrate_serial(paths, a.method, options, params_dir=a.params_dir)
    else:
        init_ray(a.address, a.num_cpus)
        rows = calibrate_fleet(paths, a.method, options, a.cpus_per_task, params_dir=a.params_dir)
    wall = time.perf_counter() - t0
    write_table(rows, a.out)
    failed = [r for r in rows if r["status"] != "ok"]
    print(f"{len(rows)} drive{'' if len(rows) == 1 else 's'} in {wall:.1f} s, {len(failed)} failed; wrote {a.out}")
    for r in failed:
        print(f"  {r['drive']}: {r['error']}", file=sys.stderr)
    return 0 if not failed else 2


if __name__ == "__main__":
    sys.exit(main())
