//! One compensation QP (K = 650, SPEC default segment length): the
//! structured Riccati interior-point solver against Clarabel, on the same
//! seeded instances, side by side in one group.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use odocal::compensate::qp::clarabel::ClarabelSolver;
use odocal::compensate::qp::riccati::StructuredSolver;
use odocal::compensate::qp::{random_instance, QpSolver};
use std::hint::black_box;

const STAGES: usize = 650;

fn qp_solve(c: &mut Criterion) {
    let mut group = c.benchmark_group("qp_solve_k650");
    let solvers: [(&str, Box<dyn QpSolver>); 2] =
        [("structured", Box::new(StructuredSolver::default())), ("clarabel", Box::new(ClarabelSolver::default()))];
    for (label, tightness) in [("loose", 0.0), ("tight", 0.95)] {
        let instances: Vec<_> = (0..4).map(|seed| random_instance(seed, STAGES, tightness)).collect();
        for (name, solver) in &solvers {
            group.bench_with_input(BenchmarkId::new(*name, label), &instances, |b, instances| {
                let mut i = 0;
                b.iter(|| {
                    i = (i + 1) % instances.len();
                    black_box(solver.solve(black_box(&instances[i]), None))
                })
            });
        }
    }
    // Warm start from the solution of a nearby instance (as in the
    // re-linearisation loop).
    let qp0 = random_instance(7, STAGES, 0.0);
    let structured = StructuredSolver::default();
    if let Ok(prev) = structured.solve(&qp0, None) {
        let mut qp = qp0.clone();
        for c in &mut qp.c {
            *c *= 1.01;
        }
        group.bench_function(BenchmarkId::new("structured_warm", "loose"), |b| {
            b.iter(|| black_box(structured.solve(black_box(&qp), Some(&prev))))
        });
    }
    group.finish();
}

criterion_group!(benches, qp_solve);
criterion_main!(benches);
