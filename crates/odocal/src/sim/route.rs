//! The route (curvature versus distance, speed limits and stops), the speed
//! profile along it and the noise processes of the measured signals.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::{SimOptions, SpeedOptions, SPEED_GRID_M};

/// A random stream of the seed; stream 0 is the route, the others are noise sources.
pub(super) fn stream(seed: u64, id: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(id);
    rng
}

fn uniform(rng: &mut ChaCha8Rng, r: [f64; 2]) -> f64 {
    r[0] + (r[1] - r[0]) * rng.random::<f64>()
}

fn log_uniform(rng: &mut ChaCha8Rng, r: [f64; 2]) -> f64 {
    r[0] * (r[1] / r[0]).powf(rng.random::<f64>())
}

fn random_sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.random::<bool>() {
        1.0
    } else {
        -1.0
    }
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample::<f64, _>(StandardNormal)
}

/// Piecewise-linear curvature profile, speed limits and stops along s.
#[derive(Debug, Default)]
pub(super) struct Route {
    /// Knot distances, m, non-decreasing, starting at 0.
    pub(super) s: Vec<f64>,
    /// Curvature at the knots, 1/m (positive to the left).
    kappa: Vec<f64>,
    /// Speed limit pieces `(end distance, limit)`, in order.
    limits: Vec<(f64, f64)>,
    /// Stops `(distance, standstill duration)`, in order.
    stops: Vec<(f64, f64)>,
}

impl Route {
    fn end(&self) -> f64 {
        self.s.last().copied().unwrap_or(0.0)
    }

    fn push(&mut self, len: f64, kappa: f64) {
        if len > 0.0 {
            let s = self.end() + len;
            self.s.push(s);
            self.kappa.push(kappa);
        }
    }

    fn current_kappa(&self) -> f64 {
        self.kappa.last().copied().unwrap_or(0.0)
    }

    fn straight(&mut self, len: f64) {
        let k = self.current_kappa();
        self.push(len, k);
    }

    /// A sequence of curvature levels `(κ_i, heading change θ_i)`, each
    /// entered and left through clothoids of length `lt`, back to κ = 0.
    /// Each level is held for `θ_i/κ_i − lt` (at least 0), so that with the
    /// halves of its two adjacent transitions it turns by θ_i.
    fn levels(&mut self, levels: &[(f64, f64)], lt: f64) {
        for &(kappa, angle) in levels {
            self.push(lt, kappa);
            self.straight((angle / kappa - lt).max(0.0));
        }
        self.push(lt, 0.0);
    }

    /// Curvature at s; `cursor` is a knot index hint for monotone queries.
    pub(super) fn kappa_at(&self, s: f64, cursor: &mut usize) -> f64 {
        let n = self.s.len();
        while *cursor + 1 < n && self.s[*cursor + 1] <= s {
            *cursor += 1;
        }
        let i = *cursor;
        if i + 1 >= n {
            return self.kappa[n - 1];
        }
        let (s0, s1) = (self.s[i], self.s[i + 1]);
        if s1 <= s0 {
            return self.kappa[i + 1];
        }
        let f = ((s - s0) / (s1 - s0)).clamp(0.0, 1.0);
        self.kappa[i] + f * (self.kappa[i + 1] - self.kappa[i])
    }

    fn limit_at(&self, s: f64, cursor: &mut usize) -> f64 {
        while *cursor + 1 < self.limits.len() && self.limits[*cursor].0 < s {
            *cursor += 1;
        }
        self.limits.get(*cursor).map(|l| l.1).unwrap_or(f64::INFINITY)
    }
}

pub(super) fn build_route(opts: &SimOptions, rng: &mut ChaCha8Rng) -> Route {
    let ro = &opts.route;
    let so = &opts.speed;
    let length = opts.length_km * 1000.0;
    let mut route = Route { s: vec![0.0], kappa: vec![0.0], ..Default::default() };
    let mut suburb = rng.random::<f64>() < ro.suburb_fraction;
    let mut zone_left = ro.zone_length_m * rng.random_range(0.5..1.5);
    while route.end() < length {
        let start = route.end();
        let cruise = uniform(rng, if suburb { so.suburb_speed_m_per_s } else { so.city_speed_m_per_s });
        route.straight(uniform(rng, if suburb { ro.suburb_straight_m } else { ro.city_straight_m }));
        let lt = uniform(rng, ro.transition_length_m);
        let p_cross = if suburb { ro.crossroad_probability / 4.0 } else { ro.crossroad_probability };
        let u = rng.random::<f64>();
        if u < p_cross {
            // 90° crossroad turn, perhaps after a stop.
            if rng.random::<f64>() < so.stop_probability {
                let dwell = uniform(rng, so.stop_duration_s);
                route.stops.push((route.end(), dwell));
            }
            let sign = random_sign(rng);
            let radius = uniform(rng, ro.crossroad_radius_m);
            route.levels(&[(sign / radius, sign * std::f64::consts::FRAC_PI_2)], lt);
        } else if u < p_cross + ro.roundabout_probability {
            // Roundabout, driven anticlockwise: deflect right, go round, exit right.
            let ring = uniform(rng, ro.roundabout_radius_m);
            let entry_radius = 1.5 * ring;
            // Exit to the right, straight on, to the left or back; the exit
            // deflection is larger than the entry one so that even the first
            // exit goes some way round the ring.
            let entry = rng.random_range(0.7..1.1);
            let exit = entry + 0.6;
            let net = [-std::f64::consts::FRAC_PI_2, 0.0, std::f64::consts::FRAC_PI_2, std::f64::consts::PI]
                [rng.random_range(0..4usize)];
            let lt = lt.min(0.5 * entry_radius * entry);
            route.levels(
                &[(-1.0 / entry_radius, -entry), (1.0 / ring, net + entry + exit), (-1.0 / entry_radius, -exit)],
                lt,
            );
        } else {
            // A bend, sometimes an S-bend.
            let sign = random_sign(rng);
            let r1 = log_uniform(rng, ro.bend_radius_m);
            let a1 = uniform(rng, ro.bend_angle_rad);
            if rng.random::<f64>() < 0.3 {
                let r2 = log_uniform(rng, ro.bend_radius_m);
                let a2 = uniform(rng, ro.bend_angle_rad);
                route.levels(&[(sign / r1, sign * a1), (-sign / r2, -sign * a2)], lt);
            } else {
                route.levels(&[(sign / r1, sign * a1)], lt);
            }
        }
        let end = route.end();
        route.limits.push((end, cruise));
        zone_left -= end - start;
        if zone_left <= 0.0 {
            suburb = rng.random::<f64>() < ro.suburb_fraction;
            zone_left = ro.zone_length_m * rng.random_range(0.5..1.5);
        }
    }
    // Cut at the requested length.
    let keep = route.s.iter().position(|&s| s >= length).unwrap_or(route.s.len() - 1);
    let mut cur = keep.saturating_sub(1);
    let k_end = route.kappa_at(length, &mut cur);
    route.s.truncate(keep);
    route.kappa.truncate(keep);
    route.s.push(length);
    route.kappa.push(k_end);
    route.stops.retain(|st| st.0 < length - 1.0);
    route
}

// ---------------------------------------------------------------------------
// Speed profile: v on a grid in s, time by constant acceleration per cell.

#[derive(Debug)]
pub(super) struct SpeedProfile {
    ds: f64,
    pub(super) v: Vec<f64>,
    /// Arrival time at each grid point, s.
    arrive: Vec<f64>,
    /// Departure time from each grid point (arrival + standstill), s.
    depart: Vec<f64>,
}

/// Distance, speed and longitudinal acceleration at one time.
#[derive(Debug, Clone, Copy)]
pub(super) struct Motion {
    pub(super) s: f64,
    pub(super) v: f64,
    pub(super) a: f64,
}

impl SpeedProfile {
    pub(super) fn new(route: &Route, so: &SpeedOptions) -> Self {
        let length = route.end();
        let cells = ((length / SPEED_GRID_M).ceil() as usize).max(1);
        let ds = length / cells as f64;
        let n = cells + 1;
        // Peak |κ| per grid cell (its ends and any knot inside): v² is linear in s
        // within a cell, so limiting both ends by the cell's peak keeps
        // v²·|κ| ≤ a_lat,max everywhere.
        let mut cell_kappa = vec![0.0f64; cells];
        let mut kc = 0usize;
        let mut at_grid = route.kappa_at(0.0, &mut kc).abs();
        for (i, ck) in cell_kappa.iter_mut().enumerate() {
            let next = route.kappa_at((i + 1) as f64 * ds, &mut kc).abs();
            *ck = at_grid.max(next);
            at_grid = next;
        }
        for (&sk, &kk) in route.s.iter().zip(&route.kappa) {
            let c = ((sk / ds).floor() as usize).min(cells - 1);
            cell_kappa[c] = cell_kappa[c].max(kk.abs());
        }
        let mut vmax = vec![0.0; n];
        let mut lc = 0usize;
        for (i, vm) in vmax.iter_mut().enumerate() {
            let s = i as f64 * ds;
            let kappa = cell_kappa[i.saturating_sub(1)].max(cell_kappa[i.min(cells - 1)]);
            let lateral =
                if kappa > 0.0 { (so.max_lateral_acceleration_m_per_s2 / kappa).sqrt() } else { f64::INFINITY };
            *vm = route.limit_at(s, &mut lc).min(lateral);
        }
        let mut dwell = vec![0.0; n];
        for &(s, d) in &route.stops {
            let i = ((s / ds).round() as usize).min(n - 1);
            vmax[i] = 0.0;
            dwell[i] += d;
        }
        vmax[0] = 0.0;
        vmax[n - 1] = 0.0;
        let mut v = vmax;
        for i in 1..n {
            v[i] = v[i].min((v[i - 1] * v[i - 1] + 2.0 * so.max_acceleration_m_per_s2 * ds).sqrt());
        }
        for i in (0..n - 1).rev() {
            v[i] = v[i].min((v[i + 1] * v[i + 1] + 2.0 * so.max_deceleration_m_per_s2 * ds).sqrt());
        }
        let mut arrive = vec![0.0; n];
        let mut depart = vec![0.0; n];
        depart[0] = dwell[0];
        for i in 1..n {
            let vs = v[i - 1] + v[i];
            arrive[i] = depart[i - 1] + if vs > 0.0 { 2.0 * ds / vs } else { 0.0 };
            depart[i] = arrive[i] + dwell[i];
        }
        SpeedProfile { ds, v, arrive, depart }
    }

    pub(super) fn duration(&self) -> f64 {
        self.depart.last().copied().unwrap_or(0.0)
    }

    /// Motion at time t; `cursor` is a grid index hint for monotone queries.
    pub(super) fn at(&self, t: f64, cursor: &mut usize) -> Motion {
        let n = self.v.len();
        while *cursor + 1 < n && self.arrive[*cursor + 1] <= t {
            *cursor += 1;
        }
        let i = *cursor;
        let s0 = i as f64 * self.ds;
        if i + 1 >= n || t < self.depart[i] {
            return Motion { s: s0, v: self.v[i].min(if i + 1 >= n { 0.0 } else { f64::INFINITY }), a: 0.0 };
        }
        let (v0, v1) = (self.v[i], self.v[i + 1]);
        let a = (v1 * v1 - v0 * v0) / (2.0 * self.ds);
        let tau = (t - self.depart[i]).clamp(0.0, self.arrive[i + 1] - self.depart[i]);
        let v = (v0 + a * tau).max(0.0);
        let s = (s0 + v0 * tau + 0.5 * a * tau * tau).min(s0 + self.ds);
        Motion { s, v, a }
    }
}

// ---------------------------------------------------------------------------
// Noise processes.

/// First-order Gauss-Markov process sampled at a fixed step (exact discretisation).
pub(crate) struct GaussMarkov {
    rng: ChaCha8Rng,
    phi: f64,
    q: f64,
    x: f64,
    on: bool,
}

impl GaussMarkov {
    pub(crate) fn new(mut rng: ChaCha8Rng, sigma: f64, tau: f64, dt: f64) -> Self {
        let on = sigma > 0.0;
        let phi = (-dt / tau).exp();
        let x = if on { sigma * normal(&mut rng) } else { 0.0 };
        GaussMarkov { rng, phi, q: sigma * (1.0 - phi * phi).sqrt(), x, on }
    }

    /// The current value; advances to the next sample.
    pub(crate) fn next(&mut self) -> f64 {
        let out = self.x;
        if self.on {
            self.x = self.phi * self.x + self.q * normal(&mut self.rng);
        }
        out
    }
}

/// White Gaussian noise.
pub(super) struct White {
    pub(super) rng: ChaCha8Rng,
    pub(super) sigma: f64,
}

impl White {
    pub(super) fn next(&mut self) -> f64 {
        if self.sigma > 0.0 {
            self.sigma * normal(&mut self.rng)
        } else {
            0.0
        }
    }
}

/// Counts encoder ticks of a wheel over each sample interval.
pub(super) struct Encoder {
    pub(super) ticks: f64,
    pub(super) revolutions: f64,
}

impl Encoder {
    /// Average rotation speed over an interval as reported by the encoder.
    pub(super) fn measure(&mut self, n: f64, ts: f64) -> f64 {
        if self.ticks <= 0.0 {
            return n;
        }
        let before = (self.revolutions * self.ticks).floor();
        self.revolutions += n * ts;
        let after = (self.revolutions * self.ticks).floor();
        (after - before) / (self.ticks * ts)
    }
}
