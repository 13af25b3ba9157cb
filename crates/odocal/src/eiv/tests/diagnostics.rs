//! The innovation diagnostics (NIS, lag-1 correlation).

use super::support::*;
use crate::eiv::*;
use crate::sim::{simulate, NoiseOptions, SimOptions};

/// A white-noise drive on a perfect reference (1 km, the simulator's noise
/// model given) and the same drive with the reference 0.5 m ahead of the
/// rear axle, not modelled.
fn white_drive_fit(lever_x: f64, null: InnovationNull) -> EivReport {
    let noise = NoiseOptions::white_wheel_only();
    let mount = crate::model::extrinsics::Extrinsics { lever_x, lever_y: 0.0, heading_offset: 0.0 };
    let out =
        simulate(&SimOptions { length_km: 1.0, noise: noise.clone(), reference_mount: mount, ..SimOptions::paper(4) })
            .expect("sim");
    let input = input_of(&out.drive);
    let opts = EivOptions {
        noise: NoiseModel::from_sim(&noise, input.sample_time_s),
        fix_noise: true,
        window_samples: 1000,
        max_iterations: 3,
        research: ResearchOptions { innovation_null: null, ..Default::default() },
        ..Default::default()
    };
    estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv")
}

fn innovation_findings(r: &EivReport) -> Vec<&EivWarning> {
    r.warnings
        .iter()
        .filter(|w| matches!(w, EivWarning::CorrelatedInnovations { .. } | EivWarning::InconsistentInnovations { .. }))
        .collect()
}

/// On a perfect reference the 5 mm position floor is not in the data, so
/// the innovations of a correct model are correlated (lag-1 ≈ 0.6–0.7) and
/// small (NIS/dof ≈ 0.4): the checks against the fitted model
/// ([`InnovationNull::FittedModel`]) flag every window, the checks
/// against the floor-free null none, and that null predicts the lag-1.
#[test]
fn innovation_checks_pass_a_correct_model_on_a_perfect_reference() {
    let r = white_drive_fit(0.0, InnovationNull::FloorsAsRegularisation);
    assert!(innovation_findings(&r).is_empty(), "{r}");
    for w in &r.windows {
        assert!(w.lag1[0] > 0.5 && w.lag1[1] > 0.5, "the floor correlates the innovations: {w:?}");
        for c in 0..2 {
            assert!((w.lag1[c] - w.lag1_without_floors[c]).abs() < 0.1, "{w:?}");
        }
        assert!((w.nis / w.nis_without_floors - 1.0).abs() < 0.15, "{w:?}");
    }
    let before = white_drive_fit(0.0, InnovationNull::FittedModel);
    let correlated = before.warnings.iter().filter(|w| matches!(w, EivWarning::CorrelatedInnovations { .. })).count();
    assert!(correlated >= before.windows.len(), "{before}");
}

/// An unmodelled reference lever arm (0.5 m) is still flagged by the
/// whiteness check against the floor-free null.
#[test]
fn innovation_checks_flag_an_unmodelled_reference_lever_arm() {
    let r = white_drive_fit(0.5, InnovationNull::FloorsAsRegularisation);
    let flagged: Vec<_> = r
        .warnings
        .iter()
        .filter(|w| matches!(w, EivWarning::CorrelatedInnovations { lag1, expected, .. } if lag1 - expected > 0.5))
        .collect();
    assert!(flagged.len() >= r.windows.len(), "{r}");
}

/// A NIS just below its band reads as below it, not as on its edge.
#[test]
fn a_nis_outside_its_band_is_printed_so_it_reads_outside() {
    let w = EivWarning::InconsistentInnovations { window: 2, nis: 0.3934, band: [0.39715292567343624, 2.0] };
    assert_eq!(w.to_string(), "window 2: NIS/dof 0.393 outside [0.397, 2.000]");
}
