//! Corrupt wheel rows dropped as they arrive, with the rule of the whole
//! import ([`Wheels::new`](super::super::wheels::Wheels::new)): a row whose
//! count jumps further than the vehicle can drive and whose following rows,
//! within [`MAX_CORRUPT_ROWS`], return to a reachable count. The decision
//! about a row waits for the rows after it.

use std::collections::VecDeque;
use std::path::Path;

use super::super::manifest::Manifest;
use super::super::wheels::{CORRUPT_SLACK_S, MAX_CORRUPT_ROWS};
use super::condition::Row;
use super::tracks::Rotation;
use crate::error::Result;

/// The filter: each row's rotation over all rows (the jump test's), the
/// rows not yet decided, and the last kept row the jumps are judged from.
#[derive(Debug)]
pub(crate) struct CorruptFilter {
    all: [Rotation; 2],
    pending: VecDeque<(Row, [f64; 2])>,
    anchor: Option<(f64, [f64; 2])>,
    c_e: f64,
    vmax: f64,
    /// Rows dropped, and where the first three were.
    pub dropped: usize,
    pub first: Vec<String>,
}

impl CorruptFilter {
    pub(crate) fn new(m: &Manifest, all: [Rotation; 2]) -> CorruptFilter {
        CorruptFilter {
            all,
            pending: VecDeque::new(),
            anchor: None,
            c_e: m.output.theta0[0],
            vmax: m.limits.max_speed_m_per_s,
            dropped: 0,
            first: Vec::new(),
        }
    }

    fn reachable(&self, a: (f64, [f64; 2]), b: &(Row, [f64; 2])) -> bool {
        let d = self.vmax * ((b.0.t - a.0).abs() + CORRUPT_SLACK_S);
        (b.1[0] - a.1[0]).abs() * self.c_e <= d && (b.1[1] - a.1[1]).abs() * self.c_e <= d
    }

    /// Takes a row; returns the rows decided to be kept, in order.
    pub(crate) fn push(&mut self, path: &Path, row: Row, kept: &mut Vec<Row>) -> Result<()> {
        let cum = [self.all[0].next(path, &row)?, self.all[1].next(path, &row)?];
        self.pending.push_back((row, cum));
        self.decide(false, kept);
        Ok(())
    }

    /// The stream has ended: decides the rows left.
    pub(crate) fn end(&mut self, kept: &mut Vec<Row>) {
        self.decide(true, kept);
    }

    fn drop_front(&mut self) {
        if let Some((r, _)) = self.pending.pop_front() {
            self.dropped += 1;
            if self.first.len() < 3 {
                self.first.push(match r.line {
                    Some(l) => format!("line {l} (t = {:.3} s)", r.t),
                    None => format!("t = {:.3} s", r.t),
                });
            }
        }
    }

    fn keep_front(&mut self, kept: &mut Vec<Row>) {
        if let Some((r, c)) = self.pending.pop_front() {
            self.anchor = Some((r.t, c));
            kept.push(r);
        }
    }

    fn decide(&mut self, ended: bool, kept: &mut Vec<Row>) {
        if self.anchor.is_none() {
            if self.pending.len() >= 3 {
                let first = (self.pending[0].0.t, self.pending[0].1);
                let second = (self.pending[1].0.t, self.pending[1].1);
                if !self.reachable(first, &self.pending[1]) && self.reachable(second, &self.pending[2]) {
                    self.drop_front();
                }
                self.keep_front(kept);
                return self.decide(ended, kept);
            }
            if ended {
                while !self.pending.is_empty() {
                    self.keep_front(kept);
                }
            }
            return;
        }
        while let Some(a) = self.anchor {
            if self.pending.is_empty() || (!ended && self.pending.len() < MAX_CORRUPT_ROWS + 1) {
                return;
            }
            if self.reachable(a, &self.pending[0]) {
                self.keep_front(kept);
                continue;
            }
            let upto = (MAX_CORRUPT_ROWS + 1).min(self.pending.len());
            match (1..upto).find(|&j| self.reachable(a, &self.pending[j])) {
                Some(j) => {
                    for _ in 0..j {
                        self.drop_front();
                    }
                    self.keep_front(kept);
                }
                None => self.keep_front(kept),
            }
        }
    }
}
