//! The checks of a parsed manifest: values within their ranges and limits,
//! settings a signal requires present, stream names that exist. Every error
//! names the key; the first failing check is the error.

use super::{BankSpec, ClockOffset, LateralAccelerationSpec, Manifest, PositionSpec, SideslipSpec, WheelSignal};
use crate::error::Result;
use crate::io::import::limits::{self, echo_num};

impl Manifest {
    /// Checks values and cross references, naming the key.
    pub(crate) fn check(&self) -> Result<()> {
        self.check_output()?;
        self.check_streams()?;
        self.check_wheels()?;
        self.check_pose()?;
        self.check_lateral()?;
        if let Some(r) = &self.reference {
            r.check().map_err(|(key, reason)| self.error(key, reason))?;
        }
        Ok(())
    }

    /// `[output]` and `[limits]`: the output rate in Hz within its limits,
    /// the longest bridged gap and clock offsets positive and bounded, a
    /// finite given clock offset, a valid θ_0.
    fn check_output(&self) -> Result<()> {
        let o = &self.output;
        self.require_positive("output.rate_hz", o.rate_hz)?;
        self.require_at_most(
            "output.rate_hz",
            o.rate_hz,
            limits::MAX_OUTPUT_RATE_HZ,
            "the model runs at tens of Hz (40 in the paper) and a drive's sample time is at least 1 ms",
        )?;
        if o.rate_hz < limits::MIN_OUTPUT_RATE_HZ {
            return Err(self.error(
                "output.rate_hz",
                format!(
                    "{} Hz is below {} Hz: give the rate in Hz, not the step",
                    o.rate_hz,
                    limits::MIN_OUTPUT_RATE_HZ
                ),
            ));
        }
        self.require_positive("output.max_gap_s", o.max_gap_s)?;
        self.require_at_most(
            "output.max_gap_s",
            o.max_gap_s,
            limits::MAX_GAP_S,
            "a longer gap is bridged by interpolation, not data: let it split the drive into parts",
        )?;
        self.require_positive("output.max_clock_offset_s", o.max_clock_offset_s)?;
        self.require_at_most(
            "output.max_clock_offset_s",
            o.max_clock_offset_s,
            limits::MAX_CLOCK_OFFSET_S,
            "clocks further apart mean a wrong time_column, time_unit or time_offset_s: fix those instead",
        )?;
        self.require_positive("limits.max_speed_m_per_s", self.limits.max_speed_m_per_s)?;
        self.require_positive(
            "limits.max_lateral_acceleration_m_per_s2",
            self.limits.max_lateral_acceleration_m_per_s2,
        )?;
        if !non_negative(o.min_part_s) {
            return Err(self.error("output.min_part_s", format!("must be >= 0, found {}", o.min_part_s)));
        }
        if let ClockOffset::Seconds(v) = o.clock_offset {
            if !v.is_finite() {
                return Err(self.error("output.clock_offset", "must be \"auto\" or a finite number of seconds"));
            }
            self.require_at_most(
                "output.clock_offset",
                v.abs(),
                limits::MAX_CLOCK_OFFSET_S,
                "clocks further apart mean a wrong time_column, time_unit or time_offset_s: fix those instead",
            )?;
        }
        crate::model::limits::check_theta(&o.theta0()).map_err(|e| self.error("output.theta0", e))
    }

    /// `[streams]`: at least one; per stream a nominal rate and a dejitter
    /// window within their limits (the window at most so many samples each
    /// side), a finite time offset.
    fn check_streams(&self) -> Result<()> {
        if self.streams.is_empty() {
            return Err(self.error("streams", "no streams given"));
        }
        for (name, s) in &self.streams {
            if let Some(r) = s.nominal_rate_hz {
                let key = format!("streams.{name}.nominal_rate_hz");
                self.require_positive(&key, r)?;
                self.require_at_most(&key, r, limits::MAX_NOMINAL_RATE_HZ, "give the sensor's sample rate in Hz")?;
            }
            let key = format!("streams.{name}.dejitter_window_s");
            self.require_positive(&key, s.dejitter_window_s)?;
            self.require_at_most(
                &key,
                s.dejitter_window_s,
                limits::MAX_DEJITTER_WINDOW_S,
                "a few seconds follow clock drift",
            )?;
            if let Some(r) = s.nominal_rate_hz {
                let half = s.dejitter_window_s * r / 2.0;
                if half > limits::MAX_DEJITTER_HALF_WINDOW as f64 {
                    return Err(self.error(
                        &key,
                        format!(
                            "{} s at nominal_rate_hz = {r} is {} samples each side, above the limit of {}; \
                             shorten the window",
                            s.dejitter_window_s,
                            echo_num(half.round()),
                            limits::MAX_DEJITTER_HALF_WINDOW
                        ),
                    ));
                }
            }
            let key = format!("streams.{name}.time_offset_s");
            if !s.time_offset_s.is_finite() {
                return Err(self.error(&key, "must be finite"));
            }
            self.require_at_most(
                &key,
                s.time_offset_s.abs(),
                limits::MAX_TIME_OFFSET_S,
                "an offset between two clocks is at most the time between their epochs; check its unit (s)",
            )?;
        }
        Ok(())
    }

    /// `[wheels]`: an existing stream, signs ±1, and what the signal needs
    /// to become rev/s (a circumference for m/s, ticks per revolution for
    /// ticks, the counter width for raw counters).
    fn check_wheels(&self) -> Result<()> {
        let w = &self.wheels;
        self.require_stream("wheels.stream", &w.stream)?;
        self.require_sign("wheels.rear_left.sign", w.rear_left.sign)?;
        self.require_sign("wheels.rear_right.sign", w.rear_right.sign)?;
        match w.signal {
            WheelSignal::MPerS => match w.circumference_m {
                Some(c) => self.require_positive("wheels.circumference_m", c)?,
                None => return Err(self.error("wheels.circumference_m", "required for signal = \"m_per_s\"")),
            },
            WheelSignal::TicksCumulative | WheelSignal::TicksRaw => match w.ticks_per_rev {
                Some(c) => self.require_positive("wheels.ticks_per_rev", c)?,
                None => return Err(self.error("wheels.ticks_per_rev", "required for tick signals")),
            },
            WheelSignal::RevPerS | WheelSignal::RadPerS | WheelSignal::RadCumulative => {}
        }
        if w.signal == WheelSignal::TicksRaw {
            match w.counter_bits {
                Some(b) if (1..=64).contains(&b) => {}
                Some(b) => return Err(self.error("wheels.counter_bits", format!("must be 1..=64, found {b}"))),
                None => return Err(self.error("wheels.counter_bits", "required for signal = \"ticks_raw\"")),
            }
        }
        Ok(())
    }

    /// The `[wheels]` keys the chosen signal does not use, each as a notice
    /// (`wheels.circumference_m = 2 does not apply to …: ignored`): a key
    /// meant for another signal usually means the signal is the wrong one.
    pub(crate) fn unused_wheel_keys(&self) -> Vec<String> {
        let w = &self.wheels;
        let signal =
            serde_json::to_value(w.signal).ok().and_then(|v| v.as_str().map(str::to_string)).unwrap_or_default();
        let ticks = matches!(w.signal, WheelSignal::TicksCumulative | WheelSignal::TicksRaw);
        let unused = [
            (
                "circumference_m",
                w.circumference_m.filter(|_| w.signal != WheelSignal::MPerS).map(|v| v.to_string()),
                "m_per_s",
            ),
            (
                "ticks_per_rev",
                w.ticks_per_rev.filter(|_| !ticks).map(|v| v.to_string()),
                "ticks_cumulative and ticks_raw",
            ),
            (
                "counter_bits",
                w.counter_bits.filter(|_| w.signal != WheelSignal::TicksRaw).map(|v| v.to_string()),
                "ticks_raw",
            ),
        ];
        unused
            .into_iter()
            .filter_map(|(key, value, only)| {
                Some(format!(
                    "wheels.{key} = {} does not apply to signal = \"{signal}\" (only to {only}): ignored; check \
                     wheels.signal",
                    value?
                ))
            })
            .collect()
    }

    /// `[pose]`: an existing stream, a non-negative speed and a baseline in
    /// range for derived headings, a latitude/longitude origin in range, a
    /// quality filter that accepts something and has finite thresholds.
    fn check_pose(&self) -> Result<()> {
        self.require_stream("pose.stream", &self.pose.stream)?;
        if !non_negative(self.pose.derive_heading_min_speed_m_per_s) {
            return Err(self.error("pose.derive_heading_min_speed_m_per_s", "must be >= 0"));
        }
        self.require_positive("pose.derive_heading_baseline_m", self.pose.derive_heading_baseline_m)?;
        self.require_at_most(
            "pose.derive_heading_baseline_m",
            self.pose.derive_heading_baseline_m,
            limits::MAX_DERIVE_HEADING_BASELINE_M,
            "the derived heading is the mean direction over this much travel, and a curve much shorter than \
             it is smoothed away",
        )?;
        if let PositionSpec::LatLon { origin: Some(o), .. } = &self.pose.position {
            if !(o[0].abs() <= 90.0 && o[1].abs() <= 360.0 && o[2].is_finite()) {
                return Err(self.error("pose.position.origin", "expected [lat_deg, lon_deg, h_m]"));
            }
        }
        if let Some(q) = &self.pose.quality {
            if q.accept.is_empty() && q.max.is_none() && q.min.is_none() {
                return Err(self.error(
                    "pose.quality.accept",
                    "no accepted values given (give `accept = [...]`, a threshold `max = ...` / `min = ...`, or both)",
                ));
            }
            for (key, v) in [("pose.quality.max", q.max), ("pose.quality.min", q.min)] {
                if v.is_some_and(|v| !v.is_finite()) {
                    return Err(self.error(key, "must be a finite number"));
                }
            }
        }
        Ok(())
    }

    /// `[lateral_acceleration]` and `[sideslip]`: existing streams and
    /// signs ±1 for measured columns; a non-negative smoothing and a valid
    /// bank for derived a_y.
    fn check_lateral(&self) -> Result<()> {
        match &self.lateral_acceleration {
            LateralAccelerationSpec::Imu { stream, sign: s, .. } => {
                self.require_stream("lateral_acceleration.stream", stream)?;
                self.require_sign("lateral_acceleration.sign", *s)?;
            }
            LateralAccelerationSpec::FromWheels { smoothing_s, bank }
            | LateralAccelerationSpec::FromPose { smoothing_s, bank } => {
                if !non_negative(*smoothing_s) {
                    return Err(self.error("lateral_acceleration.smoothing_s", "must be >= 0"));
                }
                self.require_at_most(
                    "lateral_acceleration.smoothing_s",
                    *smoothing_s,
                    limits::MAX_SMOOTHING_S,
                    "a moving average of a few tenths of a second to a second keeps the curves",
                )?;
                if let Some(b) = bank {
                    self.check_bank(b)?;
                }
            }
        }
        if let SideslipSpec::Column { stream, sign: s, .. } = &self.sideslip {
            self.require_stream("sideslip.stream", stream)?;
            self.require_sign("sideslip.sign", *s)?;
        }
        Ok(())
    }

    /// Checks `[lateral_acceleration.bank]`.
    fn check_bank(&self, b: &BankSpec) -> Result<()> {
        const K: &str = "lateral_acceleration.bank";
        self.require_stream(&format!("{K}.left"), &b.left)?;
        self.require_stream(&format!("{K}.right"), &b.right)?;
        if b.left == b.right {
            return Err(self.error(
                &format!("{K}.right"),
                format!("the right antenna's stream is the left one's ('{}'): two antennas are needed", b.left),
            ));
        }
        self.require_positive(&format!("{K}.baseline_m"), b.baseline_m)?;
        self.require_at_most(
            &format!("{K}.baseline_m"),
            b.baseline_m,
            BankSpec::MAX_BASELINE_M,
            "give the distance between the two antennas in metres",
        )?;
        if !(b.height_offset_m.is_finite() && b.height_offset_m.abs() < b.baseline_m) {
            return Err(self.error(
                &format!("{K}.height_offset_m"),
                format!(
                    "must be a finite number of metres smaller in size than baseline_m = {}, found {}",
                    echo_num(b.baseline_m),
                    echo_num(b.height_offset_m)
                ),
            ));
        }
        if !(non_negative(b.smoothing_s) && b.smoothing_s.is_finite()) {
            return Err(self.error(&format!("{K}.smoothing_s"), format!("must be >= 0, found {}", b.smoothing_s)));
        }
        self.require_at_most(
            &format!("{K}.smoothing_s"),
            b.smoothing_s,
            limits::MAX_SMOOTHING_S,
            "a moving average over about a second keeps the curves' roll",
        )?;
        if !(b.max_roll_deg > 0.0 && b.max_roll_deg <= BankSpec::MAX_ROLL_LIMIT_DEG) {
            return Err(self.error(
                &format!("{K}.max_roll_deg"),
                format!("must be in (0, {}] degrees, found {}", BankSpec::MAX_ROLL_LIMIT_DEG, echo_num(b.max_roll_deg)),
            ));
        }
        if let Some(q) = &b.quality {
            if q.accept.is_empty() && q.max.is_none() && q.min.is_none() {
                return Err(self.error(&format!("{K}.quality.accept"), "no accepted values given"));
            }
        }
        Ok(())
    }

    /// `v` is a positive finite number.
    fn require_positive(&self, key: &str, v: f64) -> Result<()> {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(self.error(key, format!("must be a positive number, found {}", echo_num(v))))
        }
    }

    /// `v` is at most `max`; `why` says what a larger value means.
    fn require_at_most(&self, key: &str, v: f64, max: f64, why: &str) -> Result<()> {
        if v <= max {
            Ok(())
        } else {
            Err(self.error(key, format!("{} is above the limit of {max}; {why}", echo_num(v))))
        }
    }

    /// A stream of that name is declared.
    fn require_stream(&self, key: &str, name: &str) -> Result<()> {
        if self.streams.contains_key(name) {
            Ok(())
        } else {
            let known: Vec<&str> = self.streams.keys().map(String::as_str).collect();
            Err(self.error(key, format!("no stream named '{name}' (streams: {})", known.join(", "))))
        }
    }

    /// `v` is 1 or -1.
    fn require_sign(&self, key: &str, v: f64) -> Result<()> {
        if (v.abs() - 1.0).abs() < f64::EPSILON {
            Ok(())
        } else {
            Err(self.error(key, format!("must be 1 or -1, found {v}")))
        }
    }
}

/// `v ≥ 0` (false for NaN).
fn non_negative(v: f64) -> bool {
    v >= 0.0
}
