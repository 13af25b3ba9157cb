//! The 3-step method's input compensation (step 2) through its public
//! entry point, `compensate_segments`: the first selected segments of a
//! simulated paper drive (K = 650 steps each, the default of docs/method.md §5), compensated at
//! the paper's θ_0 with the structured Riccati interior-point solver and
//! with Clarabel, side by side in one group. Each compensation runs its
//! re-linearisation loop (warm-started QPs) to convergence, as in a
//! calibration; "tight" halves the wheel-rotation box, so more bounds are
//! active.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use odocal::compensate::{compensate_segments, CompensateOptions, QpOptions, SolverKind};
use odocal::segment::{calibration_segments, SegmentOptions};
use odocal::sim::{simulate, SimOptions};
use odocal::Theta;
use std::hint::black_box;

/// Segments compensated per iteration.
const SEGMENTS: usize = 4;

fn qp_solve(c: &mut Criterion) {
    let drive = simulate(&SimOptions { length_km: 6.0, ..SimOptions::paper(1) }).expect("simulate").drive;
    let selected = calibration_segments(&drive, &SegmentOptions::default()).expect("segments");
    let segments: Vec<_> = selected.iter().take(SEGMENTS).cloned().collect();
    let thetas = [Theta::PAPER_INITIAL];
    let mut group = c.benchmark_group("compensate_4_segments_k650");
    group.sample_size(10);
    for (label, input_box_rel) in [("loose", 0.05), ("tight", 0.025)] {
        let opts = CompensateOptions { input_box_rel, ..Default::default() };
        for (name, solver) in [("structured", SolverKind::Structured), ("clarabel", SolverKind::Clarabel)] {
            let qp = QpOptions::from(solver);
            group.bench_function(BenchmarkId::new(name, label), |b| {
                b.iter(|| {
                    compensate_segments(black_box(&drive), &segments, &thetas, &opts, &qp, None).expect("compensate")
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, qp_solve);
criterion_main!(benches);
