//! Gated write-back: when an online estimate may replace the stored
//! parameters.
//!
//! An update is proposed only when every gate passes:
//! 1. **σ**: each parameter's σ is below its threshold;
//! 2. **steady**: each parameter has stayed within its σ threshold of its
//!    current value for [`Gates::steady_s`] of informative driving (folded,
//!    turning segments: idling and straight driving do not count);
//! 3. **bounded change**: each parameter moved from the stored value by at
//!    most its limit, and the drive's own estimate (its data alone, without
//!    the recursion's prior; [`Status::drive_estimate`](crate::Status::drive_estimate))
//!    does not put it beyond that limit by more than 3 of its σ; a larger
//!    change is *flagged* for a person instead of written. The recursion
//!    follows a change only as fast as its random walk allows, so after a
//!    step (a tyre change) its estimate can lie well within the limit while
//!    the drive's data lie far beyond. A stored θ that is only an initial
//!    guess (no calibration recorded yet) is not a bound;
//! 4. **settled**: each parameter of the estimate lies within 3 σ of the
//!    drive's own estimate (σ of the two combined): an estimate still on its way from the
//!    stored θ to what the drive shows is not written, nor is its σ, which
//!    would not cover the distance left;
//! 5. **held-out**: on the drive's most recent validation segments the
//!    online estimate (the θ known when each started) dead-reckons better
//!    than the stored θ.

use serde::{Deserialize, Serialize};

use super::Calibrator;
use odocal::model::{Theta, THETA_NAMES};

/// The gates' thresholds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Gates {
    /// Largest σ of `c_e` as a fraction of `c_e`. Default 1e-3 (0.1 %).
    pub max_sigma_c_e_relative: f64,
    /// Largest σ of `c_d`, m. Default 1e-3.
    pub max_sigma_c_d_m: f64,
    /// Largest σ of `t_r`, m. Default 0.02.
    pub max_sigma_t_r_m: f64,
    /// Largest σ of `d`, m/(m/s²). Default 1e-3.
    pub max_sigma_d: f64,
    /// Informative driving over which each parameter must have stayed
    /// within its σ threshold of its current value, s. Default 10.
    pub steady_s: f64,
    /// Largest change of `c_e` from the stored value written without a
    /// person, as a fraction. Default 0.01 (1 %).
    pub max_change_c_e_relative: f64,
    /// Largest change of `c_d`, m. Default 5e-3.
    pub max_change_c_d_m: f64,
    /// Largest change of `t_r`, m. Default 0.05.
    pub max_change_t_r_m: f64,
    /// Largest change of `d`, m/(m/s²). Default 5e-3.
    pub max_change_d: f64,
}

impl Default for Gates {
    fn default() -> Self {
        Gates {
            max_sigma_c_e_relative: 1e-3,
            max_sigma_c_d_m: 1e-3,
            max_sigma_t_r_m: 0.02,
            max_sigma_d: 1e-3,
            steady_s: 10.0,
            max_change_c_e_relative: 0.01,
            max_change_c_d_m: 5e-3,
            max_change_t_r_m: 0.05,
            max_change_d: 5e-3,
        }
    }
}

/// What the gates decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Action {
    /// Every gate passed: write the update.
    Write,
    /// A gate held it: keep the stored parameters.
    Hold,
    /// The change is beyond its limit (the estimate's, with the other gates
    /// passed, or the drive's own estimate's, whatever the other gates
    /// say): a person should look before it is written.
    Flag,
}

impl std::fmt::Display for Action {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Action::Write => "written",
            Action::Hold => "held",
            Action::Flag => "flagged",
        })
    }
}

/// The gates' decision on the calibrator's current estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GateDecision {
    /// Write, hold or flag.
    pub action: Action,
    /// One line per gate that held or flagged it; for a write, what passed.
    pub reasons: Vec<String>,
    /// The estimate judged.
    pub theta: Theta,
    /// Its σ.
    pub sigma: Theta,
}

impl Gates {
    /// Judges the calibrator's current θ against `stored` (the parameters in
    /// use); `calibrated`: `stored` is a recorded calibration (else an
    /// initial guess, which does not bound the change).
    pub fn decide(&self, cal: &Calibrator, stored: &Theta, calibrated: bool) -> GateDecision {
        let (theta, sigma) = (cal.theta(), cal.sigma());
        let (th, sd, st) = (<[_; 4]>::from(theta), <[_; 4]>::from(sigma), <[_; 4]>::from(stored));
        let mut held = Vec::new();
        let max_sigma =
            [self.max_sigma_c_e_relative * th[0].abs(), self.max_sigma_c_d_m, self.max_sigma_t_r_m, self.max_sigma_d];
        for i in 0..4 {
            if exceeds(sd[i], max_sigma[i]) {
                held.push(format!("σ of {} {:.3e} above {:.3e}", THETA_NAMES[i], sd[i], max_sigma[i]));
            }
        }
        let steady = cal.steady_for_s(max_sigma);
        if steady < self.steady_s {
            held.push(format!("steady for {steady:.1} s of informative driving, fewer than {:.1} s", self.steady_s));
        }
        let recent: Vec<_> = cal.recent_validation().collect();
        let online: f64 = recent.iter().map(|s| s.prequential_m).sum();
        let stored_sum: Option<f64> = recent.iter().map(|s| s.stored_m).sum();
        match stored_sum {
            _ if recent.is_empty() => held.push("no validation segment scored on this drive".into()),
            Some(s) if online < s => {}
            Some(s) => held.push(format!(
                "not better than the stored θ on the last {} validation segment{}: Ē_p {:.3} m against {:.3} m",
                recent.len(),
                if recent.len() == 1 { "" } else { "s" },
                online / recent.len() as f64,
                s / recent.len() as f64
            )),
            None => held.push("no stored θ scored on the validation segments".into()),
        }
        let max_change = [
            self.max_change_c_e_relative * st[0].abs(),
            self.max_change_c_d_m,
            self.max_change_t_r_m,
            self.max_change_d,
        ];
        let mut flagged: Vec<String> = (0..4)
            .filter(|&i| calibrated && exceeds((th[i] - st[i]).abs(), max_change[i]))
            .map(|i| format!("{} changes by {:.3e}, beyond {:.3e}", THETA_NAMES[i], th[i] - st[i], max_change[i]))
            .collect();
        let mut unsettled = Vec::new();
        let mut shown = false;
        if let Some(own) = cal.drive_estimate() {
            let (ot, os) = (<[_; 4]>::from(own.theta), <[_; 4]>::from(own.sigma));
            for i in 0..4 {
                let change = ot[i] - st[i];
                if calibrated && change.abs() > max_change[i] + OWN_SIGMAS * os[i] {
                    shown = true;
                    flagged.push(format!(
                        "this drive alone puts {} at {:.6e} ± {:.1e}, {change:+.3e} from the stored value, beyond \
                         {:.3e}: a change the recursion follows only slowly",
                        THETA_NAMES[i], ot[i], os[i], max_change[i]
                    ));
                }
                // Both σ: the recursion's estimate follows its latest
                // segments more than the drive's own weighs them all.
                let apart = (th[i] - ot[i]).abs() / sd[i].hypot(os[i]);
                if apart.is_nan() || apart > OWN_SIGMAS {
                    unsettled.push(format!(
                        "{} {:.6e} lies {apart:.1} σ from this drive's own estimate {:.6e} ± {:.1e} (σ of both): \
                         not settled on the drive's data",
                        THETA_NAMES[i], th[i], ot[i], os[i]
                    ));
                }
            }
        }
        // An unsettled estimate is held, unless the drive shows a change a
        // person should look at (then the reasons tell both).
        if flagged.is_empty() {
            held.append(&mut unsettled);
        } else {
            flagged.append(&mut unsettled);
        }
        // A change the drive's own data show beyond its limit is flagged
        // for a person even when another gate holds the update (its
        // reasons follow): held, it would pass unnoticed.
        let (action, reasons) = if shown {
            (Action::Flag, flagged.into_iter().chain(held).collect())
        } else if !held.is_empty() {
            (Action::Hold, held.into_iter().chain(flagged).collect())
        } else if !flagged.is_empty() {
            (Action::Flag, flagged)
        } else {
            let msg = format!(
                "all gates passed: σ below thresholds, steady {steady:.1} s, Ē_p {:.3} m against the stored θ's {:.3} m",
                online / recent.len() as f64,
                stored_sum.unwrap_or(f64::NAN) / recent.len() as f64
            );
            (Action::Write, vec![msg])
        };
        GateDecision { action, reasons, theta, sigma }
    }
}

/// How many of the drive's own σ the estimate may lie from the drive's own
/// estimate, and the drive's own estimate beyond a change limit before
/// it is flagged.
const OWN_SIGMAS: f64 = 3.0;

/// True when `v` is above `limit` or not a number.
pub(crate) fn exceeds(v: f64, limit: f64) -> bool {
    v.is_nan() || v > limit
}
