//! smoke
use odocal::qp::{clarabel::ClarabelSolver, kkt_residual, random_instance, riccati::StructuredSolver, QpSolver};
fn main() {
    for &(seed, k, t) in &[(8350u64, 48usize, 0.0), (11, 200, 0.0), (12, 200, 0.9), (13, 120, 0.98)] {
        let qp = random_instance(seed, k, t);
        let c = ClarabelSolver::default().solve(&qp, None).unwrap();
        let s = StructuredSolver::default().solve(&qp, None).unwrap();
        let d = odocal::qp::solve_equality_constrained(&qp).unwrap();
        println!(
            "seed {seed}: c {:.12e} s {:.12e} d {:.12e} act {} {} {} it {} {}",
            c.objective,
            s.objective,
            d.objective,
            c.active_bounds,
            s.active_bounds,
            d.active_bounds,
            c.iterations,
            s.iterations
        );
        println!("  c {:?}\n  s {:?}", kkt_residual(&qp, &c).unwrap(), kkt_residual(&qp, &s).unwrap());
    }
}
