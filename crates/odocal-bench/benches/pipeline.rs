//! Benchmarks of the calibration pipeline on seeded simulated drives.
//!
//! `cargo bench -p odocal-bench --bench pipeline` — groups:
//! - `model`: one model step with all Jacobians (with `--features research`:
//!   the Jacobians are research-visible in the library);
//! - `simulate`: the default 24 km paper-noise drive;
//! - `read_csv`: reading the 24 km drive's CSV (15 MB) on one thread and
//!   on all of rayon's, whose parts it parses at once;
//! - `validate`: Ē_p of one θ on all validation segments of the 24 km drive;
//! - `three_step`: the full default 3-step calibration on 6/12/24/48 km
//!   (linear growth expected);
//! - `eiv_calibrate`: `calibrate` with batch G-N (the 3-step's and the
//!   EIV's start), EIV with the noise model
//!   fixed and EIV with it estimated (the method's default), side by side on
//!   12/24/48 km (`eiv_speed` in crates/odocal-lab is the quicker way to iterate).

use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use odocal::eiv::EivOptions;
use odocal::segment::{validation_segments, ValidationSegmentOptions};
use odocal::sim::{simulate, SimOptions};
use odocal::EivMethodOptions;
use odocal::{calibrate, CalibrationOptions, Method};

fn drive(km: f64) -> odocal::Drive {
    simulate(&SimOptions { length_km: km, ..SimOptions::paper(1) }).expect("simulate").drive
}

#[cfg(feature = "research")]
fn bench_model(c: &mut Criterion) {
    use odocal::model::{step_jacobians, Input, State};
    use std::hint::black_box;
    let x = State::new(10.0, -3.0, 0.3);
    let u = Input { n_rl: 5.1, n_rr: 5.3, beta: 0.01, a_y: 1.2 };
    let theta = odocal::Theta::SIM_DEFAULT_TRUE;
    c.bench_function("model/step_jacobians", |b| {
        b.iter(|| step_jacobians(black_box(&x), black_box(&u), black_box(&theta), 0.025))
    });
}

/// Without `research` the model's Jacobians are crate-internal: no `model` group.
#[cfg(not(feature = "research"))]
fn bench_model(_: &mut Criterion) {}

fn bench_simulate(c: &mut Criterion) {
    let mut g = c.benchmark_group("simulate");
    g.sample_size(10);
    g.bench_function("paper_24km", |b| b.iter(|| simulate(&SimOptions::paper(1)).expect("simulate")));
    g.finish();
}

fn bench_read_csv(c: &mut Criterion) {
    let path = std::env::temp_dir().join(format!("odocal-bench-read-{}.csv", std::process::id()));
    drive(24.0).write_csv(&path).expect("write the drive");
    let mut g = c.benchmark_group("read_csv_24km");
    g.sample_size(20);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    g.bench_function("one_thread", |b| b.iter(|| one.install(|| odocal::Drive::read_csv(&path).expect("read"))));
    let threads = rayon::current_num_threads();
    g.bench_function(format!("{threads}_threads"), |b| b.iter(|| odocal::Drive::read_csv(&path).expect("read")));
    g.finish();
    let _ = std::fs::remove_file(&path);
}

fn bench_validate(c: &mut Criterion) {
    let d = drive(24.0);
    let val = validation_segments(&d, &ValidationSegmentOptions::default()).expect("validation");
    let theta = SimOptions::default().theta_true;
    let mut g = c.benchmark_group("validate_24km");
    g.sample_size(10);
    g.bench_function("one_theta", |b| b.iter(|| odocal::mean_position_error(&d, &val, &theta).expect("validate")));
    g.finish();
}

fn bench_three_step(c: &mut Criterion) {
    let mut g = c.benchmark_group("three_step");
    g.sample_size(10);
    g.warm_up_time(Duration::from_millis(100));
    g.measurement_time(Duration::from_secs(5));
    for km in [6.0, 12.0, 24.0, 48.0] {
        let d = drive(km);
        g.bench_with_input(BenchmarkId::from_parameter(format!("{km}km")), &d, |b, d| {
            b.iter(|| calibrate(d, &CalibrationOptions::default()).expect("calibrate"))
        });
    }
    g.finish();
}

fn bench_eiv(c: &mut Criterion) {
    let mut g = c.benchmark_group("eiv_calibrate");
    g.sample_size(10);
    g.warm_up_time(Duration::from_millis(100));
    g.measurement_time(Duration::from_secs(5));
    let eiv = |fix_noise: bool| {
        Method::Eiv(EivMethodOptions { filter: EivOptions { fix_noise, ..Default::default() }, ..Default::default() })
    };
    for km in [12.0, 24.0, 48.0] {
        let d = drive(km);
        for (name, method) in
            [("batch_gn", Method::BatchGn), ("eiv_fixed_noise", eiv(true)), ("eiv_estimated_noise", eiv(false))]
        {
            let opts = CalibrationOptions { method, ..Default::default() };
            g.bench_with_input(BenchmarkId::new(name, format!("{km}km")), &d, |b, d| {
                b.iter(|| calibrate(d, &opts).expect("calibrate"))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench_model, bench_simulate, bench_read_csv, bench_validate, bench_three_step, bench_eiv);
criterion_main!(benches);
