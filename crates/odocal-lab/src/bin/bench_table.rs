//! The performance table of docs/performance.md, in one run: wall time,
//! CPU time and peak memory of `calibrate` per method, as ratios against
//! batch Gauss-Newton measured in the same run.
//!
//! ```sh
//! cargo run --release --manifest-path crates/odocal-lab/Cargo.toml --target-dir target \
//!     --bin bench_table -- [--quick] [--reps 3] [--out DIR]
//! ```
//!
//! The drives are simulated once (the paper's route and noise, seed 1) and
//! written as CSV to `--out` (default: a directory under the system's temp
//! directory, removed at the end). Every measurement runs in a fresh worker
//! process (this program, `--worker DRIVE.csv METHOD THREADS`) that reads
//! the CSV, runs `calibrate` on a rayon pool of THREADS threads and reports
//! the wall and CPU time of the calibration alone and its peak resident
//! memory (`VmHWM`, so Linux only), which includes reading the drive as
//! `odocal calibrate` does. Repetitions are interleaved (every cell once,
//! then every cell again), so load that comes and goes on a shared
//! machine falls on every method alike; the tables give medians.
//!
//! Tables:
//! - **threads**: batch-gn, eiv (the default method) and three-step on the
//!   24 km drive with 1, 2 and all cores' threads;
//! - **length**: the same on 6/12/24/48/96 km with 2 threads (or fewer
//!   cores), with the cost per km and per sample relative to 24 km. These
//!   drives are one simulated drive of `--unit-km` (default 6 km) driven
//!   again and again (see `repeated`), so that every length has the same
//!   route, speed profile and samples per km: a simulated route of 96 km is
//!   not a longer version of the 24 km one (its zones differ, and with them
//!   its samples per km), which mixes the route's content into a per-km
//!   comparison;
//! - **fleet**: `--fleet-drives` runs of the default method on the 12 km
//!   drive (`--fleet-km`), one thread each, as many processes at once as there are cores,
//!   against the same runs one after another.
//!
//! `--quick`: lengths 6/12/24 km and a fleet on the 6 km drive (a few
//! minutes; the full run takes tens of minutes on two cores).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Instant;

use odocal::sim::{simulate, SimOptions};
use odocal::{calibrate, CalibrationOptions, Drive, DriveBuilder, Method, Signals};
use odocal_lab::{median, Args, Res, Table};

const USAGE: &str = "bench_table [--quick] [--reps 3] [--seed 1] [--threads 1,2,CORES] [--lengths 6,12,24,48,96] \
                     [--unit-km 6] [--fleet-drives 2×CORES] [--fleet-km 12] [--out DIR]\n       bench_table --worker DRIVE.csv METHOD THREADS";

/// The methods of the table, by their CLI names; the first is the reference.
const METHODS: [&str; 3] = ["batch-gn", "eiv", "three-step"];

/// The drive length the thread table and the per-km costs refer to.
const REFERENCE_KM: f64 = 24.0;

fn main() {
    let argv: Vec<String> = std::env::args().skip(1).collect();
    if argv.first().map(String::as_str) == Some("--worker") {
        odocal_lab::main_with(|| worker(&argv[1..]));
    } else {
        odocal_lab::main_with(run);
    }
}

/// One calibration, measured: prints `wall_s cpu_s peak_kb samples
/// passes`, `passes` the EIV filter's passes with derivatives (the fit's
/// and its heading-drift test's; 0 for the other methods), read from the
/// report after the clock stopped.
fn worker(argv: &[String]) -> Res<()> {
    let [path, method, threads] = argv else {
        return Err(format!("--worker needs DRIVE.csv METHOD THREADS\n\n{USAGE}").into());
    };
    let threads: usize = threads.parse()?;
    rayon::ThreadPoolBuilder::new().num_threads(threads).build_global()?;
    let (drive, _warnings) = Drive::read_csv(path)?;
    let opts = CalibrationOptions { method: method.parse::<Method>()?, ..Default::default() };
    let cpu0 = cpu_seconds()?;
    let t = Instant::now();
    let report = calibrate(&drive, &opts)?;
    let wall = t.elapsed().as_secs_f64();
    let cpu = cpu_seconds()? - cpu0;
    let peak = peak_rss_kb()?;
    let json = serde_json::to_value(&report)?;
    let with_derivatives = |v: &serde_json::Value| v.get("evaluations").and_then(|e| e.get(0)?.as_u64()).unwrap_or(0);
    let eiv = &json["eiv"];
    let passes = with_derivatives(eiv) + with_derivatives(&eiv["heading_drift"]);
    println!("{wall} {cpu} {peak} {} {passes}", drive.len());
    Ok(())
}

/// User + system CPU time of this process so far (`/proc/self/stat`).
fn cpu_seconds() -> Res<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat")?;
    // Fields after the command name (which is in parentheses and may hold spaces).
    let rest = stat.rsplit_once(')').ok_or("unreadable /proc/self/stat")?.1;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of stat(5), 12 and 13 after the name.
    let ticks: f64 =
        fields.get(11).ok_or("short stat")?.parse::<f64>()? + fields.get(12).ok_or("short stat")?.parse::<f64>()?;
    Ok(ticks / clock_ticks_per_second())
}

/// The kernel's USER_HZ: 100 on every Linux architecture Rust supports.
fn clock_ticks_per_second() -> f64 {
    100.0
}

/// Peak resident set size of this process, kB (`VmHWM` of `/proc/self/status`).
fn peak_rss_kb() -> Res<u64> {
    let status = std::fs::read_to_string("/proc/self/status")?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).ok_or("no VmHWM in /proc/self/status")?;
    Ok(line.split_whitespace().nth(1).ok_or("unreadable VmHWM")?.parse()?)
}

/// What one worker reported.
#[derive(Debug, Clone, Copy)]
struct Sample {
    wall: f64,
    cpu: f64,
    peak_kb: f64,
    samples: usize,
    /// EIV filter passes with derivatives (0 for the other methods).
    passes: u64,
}

fn parse_sample(out: &str) -> Res<Sample> {
    let v: Vec<&str> = out.split_whitespace().collect();
    let [wall, cpu, peak, samples, passes] = v[..] else {
        return Err(format!("unexpected worker output '{out}'").into());
    };
    Ok(Sample {
        wall: wall.parse()?,
        cpu: cpu.parse()?,
        peak_kb: peak.parse()?,
        samples: samples.parse()?,
        passes: passes.parse()?,
    })
}

fn worker_command(drive: &Path, method: &str, threads: usize) -> Res<Command> {
    let mut c = Command::new(std::env::current_exe()?);
    c.arg("--worker").arg(drive).arg(method).arg(threads.to_string());
    c.stdout(Stdio::piped());
    Ok(c)
}

fn wait_sample(child: Child, what: &str) -> Res<Sample> {
    let out = child.wait_with_output()?;
    if !out.status.success() {
        return Err(format!("worker {what} failed ({})", out.status).into());
    }
    parse_sample(&String::from_utf8_lossy(&out.stdout))
}

/// One measurement cell: a method on a drive with a thread count.
#[derive(Debug, Clone)]
struct Cell {
    method: &'static str,
    km: f64,
    /// A drive of the length series (the unit drive repeated) rather than
    /// a simulated drive of this length.
    series: bool,
    threads: usize,
    runs: Vec<Sample>,
}

impl Cell {
    fn median(&self, f: impl Fn(&Sample) -> f64) -> f64 {
        median(&self.runs.iter().map(f).collect::<Vec<_>>())
    }
    fn wall(&self) -> f64 {
        self.median(|s| s.wall)
    }
    fn cpu(&self) -> f64 {
        self.median(|s| s.cpu)
    }
    fn peak_mb(&self) -> f64 {
        self.runs.iter().map(|s| s.peak_kb).fold(0.0, f64::max) / 1024.0
    }
    fn samples(&self) -> usize {
        self.runs.first().map_or(0, |s| s.samples)
    }
    /// The EIV passes with derivatives, "–" for the other methods (every
    /// run of a cell takes the same: the fit is deterministic).
    fn passes(&self) -> String {
        match self.runs.first().map_or(0, |s| s.passes) {
            0 => "–".into(),
            n => n.to_string(),
        }
    }
}

fn find<'a>(cells: &'a [Cell], method: &str, km: f64, series: bool, threads: usize) -> Option<&'a Cell> {
    cells
        .iter()
        .find(|c| c.method == method && c.km.to_bits() == km.to_bits() && c.series == series && c.threads == threads)
}

/// The run's settings.
struct Plan {
    reps: usize,
    seed: u64,
    threads: Vec<usize>,
    lengths: Vec<f64>,
    unit_km: f64,
    length_threads: usize,
    fleet_km: f64,
    fleet_drives: usize,
    cores: usize,
    dir: PathBuf,
    keep_dir: bool,
}

fn parse_list<T: std::str::FromStr>(v: &[String]) -> Res<Vec<T>>
where
    T::Err: std::fmt::Display,
{
    v.iter().map(|s| s.parse::<T>().map_err(|e| format!("'{s}': {e}").into())).collect()
}

fn plan() -> Res<Plan> {
    let mut args = Args::parse(USAGE, &["quick"])?;
    let quick = args.flag("quick");
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let reps = args.get("reps", 3usize)?.max(1);
    let seed = args.get("seed", 1u64)?;
    let cores_s = cores.to_string();
    let mut threads: Vec<usize> = parse_list(&args.list("threads", &["1", "2", &cores_s]))?;
    threads.sort_unstable();
    threads.dedup();
    let default_lengths: &[&str] = if quick { &["6", "12", "24"] } else { &["6", "12", "24", "48", "96"] };
    let mut lengths: Vec<f64> = parse_list(&args.list("lengths", default_lengths))?;
    if !lengths.contains(&REFERENCE_KM) {
        lengths.push(REFERENCE_KM);
    }
    lengths.sort_by(f64::total_cmp);
    let unit_km: f64 = args.get("unit-km", 6.0)?;
    if let Some(bad) = lengths.iter().find(|&&km| copies(km, unit_km).is_none()) {
        return Err(format!("--lengths: {bad} km is not a whole multiple of --unit-km {unit_km}").into());
    }
    let fleet_drives = args.get("fleet-drives", 2 * cores)?;
    let fleet_km = args.get("fleet-km", if quick { 6.0 } else { 12.0 })?;
    let out: Option<String> = args.opt("out")?;
    args.finish()?;
    let keep_dir = out.is_some();
    let dir = out
        .map_or_else(|| std::env::temp_dir().join(format!("odocal-bench-table-{}", std::process::id())), PathBuf::from);
    Ok(Plan {
        reps,
        seed,
        threads,
        lengths,
        unit_km,
        length_threads: 2.min(cores),
        fleet_km,
        fleet_drives,
        cores,
        dir,
        keep_dir,
    })
}

/// How many drives of `unit_km` make `km` (None unless a whole number ≥ 1).
fn copies(km: f64, unit_km: f64) -> Option<usize> {
    let n = (km / unit_km).round();
    (unit_km > 0.0 && n >= 1.0 && (n * unit_km - km).abs() <= 1e-9 * km).then_some(n as usize)
}

fn drive_path(plan: &Plan, km: f64, series: bool) -> PathBuf {
    if series {
        plan.dir.join(format!(
            "drive-{km}km-{}x{}km-seed{}.csv",
            copies(km, plan.unit_km).unwrap_or(0),
            plan.unit_km,
            plan.seed
        ))
    } else {
        plan.dir.join(format!("drive-{km}km-seed{}.csv", plan.seed))
    }
}

/// The drive `unit` driven `copies` times in a row, as one drive. Each
/// copy is moved rigidly (its reference poses rotated and translated) so
/// that its true start pose is the previous copy's true end pose, and its
/// time stamps continue one sample time after the previous copy's last.
/// A simulated drive starts and ends at a standstill, so a join is the car
/// standing still for one sample more; the measured reference's noise
/// restarts there (a step of the size of that noise, about 0.5 m on the
/// 6 km drive of seed 1). The result has no truth.
fn repeated(unit: &Drive, copies: usize) -> Res<Drive> {
    let truth = unit.truth().ok_or("the unit drive has no truth")?;
    let (m, n, ts) = (unit.measured(), unit.len(), unit.sample_time_s());
    let period = unit.t()[n - 1] - unit.t()[0] + ts;
    let mut t = Vec::with_capacity(n * copies);
    let mut sig = Signals::default();
    // The rigid move of the current copy: rotation by `rot`, then translation.
    let (mut rot, mut dx, mut dy) = (0.0f64, 0.0, 0.0);
    for c in 0..copies {
        let (s, co) = rot.sin_cos();
        for i in 0..n {
            t.push(unit.t()[i] + c as f64 * period);
            sig.px.push(co * m.px[i] - s * m.py[i] + dx);
            sig.py.push(s * m.px[i] + co * m.py[i] + dy);
            sig.psi.push(m.psi[i] + rot);
        }
        sig.n_rl.extend_from_slice(&m.n_rl);
        sig.n_rr.extend_from_slice(&m.n_rr);
        sig.beta.extend_from_slice(&m.beta);
        sig.a_y.extend_from_slice(&m.a_y);
        // The next copy's true start goes where this copy's true end is.
        let end = (co * truth.px[n - 1] - s * truth.py[n - 1] + dx, s * truth.px[n - 1] + co * truth.py[n - 1] + dy);
        rot += truth.psi[n - 1] - truth.psi[0];
        let (s, co) = rot.sin_cos();
        dx = end.0 - (co * truth.px[0] - s * truth.py[0]);
        dy = end.1 - (s * truth.px[0] + co * truth.py[0]);
    }
    let builder = DriveBuilder {
        context: format!("{copies} × the unit drive"),
        t,
        measured: sig,
        sample_time_s: Some(ts),
        ..Default::default()
    };
    Ok(builder.build()?)
}

/// Simulates and writes every drive the plan needs: the reference and
/// fleet drives as simulated, the length series from the unit drive.
fn write_drives(plan: &Plan) -> Res<()> {
    std::fs::create_dir_all(&plan.dir)?;
    let simulated = |km: f64| simulate(&SimOptions { length_km: km, ..SimOptions::paper(plan.seed) });
    let mut kms = vec![REFERENCE_KM];
    if plan.fleet_drives > 0 && plan.fleet_km.to_bits() != REFERENCE_KM.to_bits() {
        kms.push(plan.fleet_km);
    }
    for km in kms {
        let path = drive_path(plan, km, false);
        if !path.exists() {
            simulated(km)?.drive.write_csv(&path)?;
        }
    }
    let unit = simulated(plan.unit_km)?.drive;
    for &km in &plan.lengths {
        let path = drive_path(plan, km, true);
        if !path.exists() {
            repeated(&unit, copies(km, plan.unit_km).ok_or("length not a multiple of the unit")?)?.write_csv(&path)?;
        }
    }
    Ok(())
}

/// The cells of the thread and length tables, each once.
fn cells(plan: &Plan) -> Vec<Cell> {
    let mut cells: Vec<Cell> = Vec::new();
    let mut add = |method: &'static str, km: f64, series: bool, threads: usize| {
        if find(&cells, method, km, series, threads).is_none() {
            cells.push(Cell { method, km, series, threads, runs: Vec::new() });
        }
    };
    for &t in &plan.threads {
        for m in METHODS {
            add(m, REFERENCE_KM, false, t);
        }
    }
    for &km in &plan.lengths {
        for m in METHODS {
            add(m, km, true, plan.length_threads);
        }
    }
    cells
}

/// Fleet timings: per repetition, the wall time of every drive in turn
/// (one process at a time) and of all drives with `cores` processes at once.
#[derive(Default)]
struct Fleet {
    serial: Vec<f64>,
    parallel: Vec<f64>,
}

/// The fleet's runs one after another: the sum of their wall times.
fn fleet_serial(plan: &Plan, path: &Path) -> Res<f64> {
    let mut total = 0.0;
    for _ in 0..plan.fleet_drives {
        total += wait_sample(worker_command(path, "eiv", 1)?.spawn()?, "fleet")?.wall;
    }
    Ok(total)
}

/// The fleet's runs, `cores` processes at a time: wall time from the first
/// start to the last end.
fn fleet_parallel(plan: &Plan, path: &Path) -> Res<f64> {
    let t = Instant::now();
    let mut running: Vec<Child> = Vec::new();
    let mut started = 0;
    while started < plan.fleet_drives || !running.is_empty() {
        while started < plan.fleet_drives && running.len() < plan.cores {
            running.push(worker_command(path, "eiv", 1)?.spawn()?);
            started += 1;
        }
        let child = running.remove(0);
        wait_sample(child, "fleet")?;
    }
    Ok(t.elapsed().as_secs_f64())
}

fn measure(plan: &Plan, cells: &mut [Cell], fleet: &mut Fleet) -> Res<()> {
    let total = cells.len();
    for rep in 0..plan.reps {
        for (i, c) in cells.iter_mut().enumerate() {
            eprint!("\rrepetition {}/{}: {} of {total} cells       ", rep + 1, plan.reps, i + 1);
            let child = worker_command(&drive_path(plan, c.km, c.series), c.method, c.threads)?.spawn()?;
            let sample = wait_sample(child, c.method)?;
            // Every sample as it comes, so an interrupted run leaves its data.
            eprintln!(
                "\rsample: {} km{}, {}, {} thread(s): {:.3} s wall, {:.2} s CPU, {:.0} kB peak",
                c.km,
                if c.series { " (series)" } else { "" },
                c.method,
                c.threads,
                sample.wall,
                sample.cpu,
                sample.peak_kb
            );
            c.runs.push(sample);
        }
        if plan.fleet_drives > 0 {
            eprint!("\rrepetition {}/{}: fleet                 ", rep + 1, plan.reps);
            let path = drive_path(plan, plan.fleet_km, false);
            fleet.serial.push(fleet_serial(plan, &path)?);
            fleet.parallel.push(fleet_parallel(plan, &path)?);
            eprintln!("\rsample: fleet: {:.2} s serial, {:.2} s parallel", fleet.serial[rep], fleet.parallel[rep]);
        }
    }
    eprintln!();
    Ok(())
}

fn ratio(x: f64, reference: f64) -> String {
    format!("{:.1}×", x / reference)
}

fn thread_table(plan: &Plan, cells: &[Cell]) -> Table {
    let mut header = vec!["method".to_string()];
    for t in &plan.threads {
        header.push(format!(">{t} thread{}", if *t == 1 { "" } else { "s" }));
    }
    header.push(">peak RSS".into());
    let mut table = Table::new(&header.iter().map(String::as_str).collect::<Vec<_>>());
    for m in METHODS {
        let mut row = vec![m.to_string()];
        let mut peak: f64 = 0.0;
        for &t in &plan.threads {
            let (Some(c), Some(b)) =
                (find(cells, m, REFERENCE_KM, false, t), find(cells, METHODS[0], REFERENCE_KM, false, t))
            else {
                continue;
            };
            peak = peak.max(c.peak_mb());
            row.push(if m == METHODS[0] {
                format!("1 ({:.2} s; CPU {:.2} s)", c.wall(), c.cpu())
            } else {
                format!("**{}** ({:.2} s; CPU {})", ratio(c.wall(), b.wall()), c.wall(), ratio(c.cpu(), b.cpu()))
            });
        }
        row.push(format!("{peak:.0} MB"));
        table.row(row);
    }
    table
}

fn length_table(plan: &Plan, cells: &[Cell]) -> Table {
    let mut table = Table::new(&[
        "km",
        ">samples",
        "method",
        ">wall",
        ">× batch-gn",
        ">CPU",
        ">CPU per km vs 24 km",
        ">wall per km vs 24 km",
        ">wall per sample vs 24 km",
        ">EIV passes",
        ">peak RSS",
    ]);
    let t = plan.length_threads;
    for &km in &plan.lengths {
        for m in METHODS {
            let (Some(c), Some(b), Some(r)) = (
                find(cells, m, km, true, t),
                find(cells, METHODS[0], km, true, t),
                find(cells, m, REFERENCE_KM, true, t),
            ) else {
                continue;
            };
            let cpu_per_km = (c.cpu() / km) / (r.cpu() / REFERENCE_KM);
            let per_km = (c.wall() / km) / (r.wall() / REFERENCE_KM);
            let per_sample = (c.wall() / c.samples() as f64) / (r.wall() / r.samples() as f64);
            table.row([
                format!("{km}"),
                c.samples().to_string(),
                m.to_string(),
                format!("{:.2} s", c.wall()),
                ratio(c.wall(), b.wall()),
                format!("{:.2} s", c.cpu()),
                format!("{cpu_per_km:.2}"),
                format!("{per_km:.2}"),
                format!("{per_sample:.2}"),
                c.passes(),
                format!("{:.0} MB", c.peak_mb()),
            ]);
        }
    }
    table
}

fn fleet_line(plan: &Plan, fleet: &Fleet) -> String {
    let serial = median(&fleet.serial);
    let parallel = median(&fleet.parallel);
    format!(
        "fleet: {} runs of eiv on the {} km drive, 1 thread each: {:.2} s one after another, {:.2} s in {} \
         processes at once: **{:.2}×** ({:.0} % of {} cores)",
        plan.fleet_drives,
        plan.fleet_km,
        serial,
        parallel,
        plan.cores,
        serial / parallel,
        100.0 * serial / parallel / plan.cores as f64,
        plan.cores
    )
}

fn machine_line(plan: &Plan) -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    format!(
        "machine: {cpu}, {} cores; filter kernels {}; load average {}",
        plan.cores,
        odocal::eiv::kernel_instruction_set(),
        load_average()
    )
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map_or_else(|_| "unknown".into(), |s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
}

fn run() -> Res<()> {
    let plan = plan()?;
    println!("{}", machine_line(&plan));
    eprintln!("writing drives to {}", plan.dir.display());
    write_drives(&plan)?;
    let mut cells = cells(&plan);
    let mut fleet = Fleet::default();
    let result = measure(&plan, &mut cells, &mut fleet);
    if !plan.keep_dir {
        std::fs::remove_dir_all(&plan.dir)?;
    }
    result?;
    println!("load average at the end: {}", load_average());
    println!(
        "medians of {} interleaved repetitions; wall time of `calibrate` (the drive read from CSV before, not \
         counted) and, beside it, the ratio of CPU times (user + system of the worker process); ratios \
         against batch-gn with the same threads and drive\n",
        plan.reps
    );
    println!(
        "{REFERENCE_KM} km drive ({} samples), by threads:\n",
        find(&cells, METHODS[0], REFERENCE_KM, false, plan.threads[0]).map_or(0, Cell::samples)
    );
    println!("{}", thread_table(&plan, &cells));
    println!(
        "by length, {} thread{}, each drive the {} km drive of seed {} driven again and again (same route and \
         samples per km at every length):\n",
        plan.length_threads,
        if plan.length_threads == 1 { "" } else { "s" },
        plan.unit_km,
        plan.seed
    );
    println!("{}", length_table(&plan, &cells));
    if plan.fleet_drives > 0 {
        println!("{}", fleet_line(&plan, &fleet));
    }
    Ok(())
}
