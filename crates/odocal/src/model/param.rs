//! Named model parameters and sets of them.
//!
//! [`Param`] names one estimated quantity; [`ParamSet`] is a set of them
//! (which are free, which are not observable, which were held). Both
//! serialise as names (`"c_e"`, `["c_d", "t_r"]`), so JSON reports read the
//! same as the paper's symbols.
//!
//! The parameters are the four of θ, then the reference sensor's
//! extrinsics (lever arm x/y and heading offset, [[`Extrinsics`](crate::Extrinsics)]),
//! which are held at their given value (default 0) unless asked for. Later
//! entries (noise scales) join as new variants after those:
//! [`Param::index`] is the position in the full parameter vector, θ's four
//! first, and [`ParamSet`] is a bit set with room for 32 entries.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::error::{Error, Result};
#[cfg(test)]
use crate::model::extrinsics::Extrinsics;
use crate::model::Theta;

/// One estimated parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Param {
    /// Effective rear wheel circumference c_e, m.
    #[serde(rename = "c_e")]
    CE,
    /// Circumference difference c_d (left minus right), m.
    #[serde(rename = "c_d")]
    CD,
    /// Rear track width t_r, m.
    #[serde(rename = "t_r")]
    TR,
    /// Load-transfer coefficient d, m per m/s².
    #[serde(rename = "d")]
    D,
    /// Lever arm of the pose reference along the vehicle's forward axis, m
    /// ([`crate::model::extrinsics::Extrinsics::lever_x`]).
    #[serde(rename = "lever_x")]
    LeverX,
    /// Lever arm of the pose reference along the vehicle's left axis, m.
    #[serde(rename = "lever_y")]
    LeverY,
    /// Heading of the pose reference minus the vehicle's, rad.
    #[serde(rename = "heading_offset")]
    HeadingOffset,
}

impl Param {
    /// The four parameters of θ, in vector order `[c_e, c_d, t_r, d]`.
    pub(crate) const THETA: [Param; 4] = [Param::CE, Param::CD, Param::TR, Param::D];
    /// The reference extrinsics, in vector order `[lever_x, lever_y, heading_offset]`.
    pub(crate) const EXTRINSICS: [Param; 3] = [Param::LeverX, Param::LeverY, Param::HeadingOffset];
    /// Every parameter, in vector order.
    pub(crate) const ALL: [Param; 7] =
        [Param::CE, Param::CD, Param::TR, Param::D, Param::LeverX, Param::LeverY, Param::HeadingOffset];

    /// The name used in reports and on the command line (`"c_e"`, …; outside
    /// the crate: `Display`).
    pub(crate) const fn name(self) -> &'static str {
        match self {
            Param::CE => "c_e",
            Param::CD => "c_d",
            Param::TR => "t_r",
            Param::D => "d",
            Param::LeverX => "lever_x",
            Param::LeverY => "lever_y",
            Param::HeadingOffset => "heading_offset",
        }
    }

    /// True for the four parameters of θ.
    #[cfg(test)]
    pub(crate) const fn is_theta(self) -> bool {
        (self as usize) < 4
    }

    /// Position among the extrinsics `[lever_x, lever_y, heading_offset]`,
    /// `None` for a θ parameter.
    pub(crate) const fn extrinsics_index(self) -> Option<usize> {
        match self {
            Param::LeverX => Some(0),
            Param::LeverY => Some(1),
            Param::HeadingOffset => Some(2),
            _ => None,
        }
    }

    /// Position in the parameter vector (θ's four first).
    pub(crate) const fn index(self) -> usize {
        self as usize
    }

    /// The parameter at vector position `i`, if there is one.
    pub(crate) fn from_index(i: usize) -> Option<Param> {
        Param::ALL.get(i).copied()
    }

    /// This parameter's value in θ; the extrinsics are not part of θ and
    /// read NaN here ([`Extrinsics::get`](crate::Extrinsics::get) reads
    /// theirs).
    pub(crate) fn value(self, theta: &Theta) -> f64 {
        match self {
            Param::CE => theta.c_e,
            Param::CD => theta.c_d,
            Param::TR => theta.t_r,
            Param::D => theta.d,
            Param::LeverX | Param::LeverY | Param::HeadingOffset => f64::NAN,
        }
    }

    /// This parameter's value in θ or in the extrinsics.
    #[cfg(test)]
    pub(crate) fn value_in(self, theta: &Theta, extrinsics: &Extrinsics) -> f64 {
        extrinsics.get(self).unwrap_or_else(|| self.value(theta))
    }
}

impl std::fmt::Display for Param {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Param {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Param::ALL.into_iter().find(|p| p.name() == s.trim()).ok_or_else(|| Error::Parse {
            what: "parameter",
            input: s.to_string(),
            expected: "c_e, c_d, t_r or d (or lever_x, lever_y, heading_offset)",
        })
    }
}

/// A set of [`Param`]s, iterated in vector order.
///
/// ```
/// use odocal::{Param, ParamSet};
/// let free = ParamSet::from_iter([Param::CE, Param::CD, Param::TR]);
/// assert_eq!(free.to_string(), "c_e, c_d, t_r");
/// assert!(free.contains(Param::TR) && !free.contains(Param::D));
/// assert_eq!("c_d,t_r".parse::<ParamSet>().unwrap(), ParamSet::from_iter([Param::CD, Param::TR]));
/// ```
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ParamSet(u32);

impl ParamSet {
    /// No parameter (as `ParamSet::default()`).
    pub(crate) const EMPTY: ParamSet = ParamSet(0);
    research_pub! {
        /// The four parameters of θ.
        const THETA: ParamSet = ParamSet(0b1111);
    }
    research_pub! {
        /// The reference extrinsics (lever_x, lever_y, heading_offset).
        const EXTRINSICS: ParamSet = ParamSet(0b111_0000);
    }
    /// The lever arm (lever_x, lever_y); `lever-arm` in a parsed list.
    pub(crate) const LEVER_ARM: ParamSet = ParamSet(0b011_0000);

    /// True when `p` is in the set.
    pub const fn contains(self, p: Param) -> bool {
        self.0 & (1 << p as u32) != 0
    }

    research_pub! {
        /// The set with `p` added.
        #[must_use]
        const fn with(self, p: Param) -> ParamSet {
            ParamSet(self.0 | 1 << p as u32)
        }
    }

    research_pub! {
        /// The set with `p` removed (outside the crate: collect the set's
        /// parameters but `p`).
        #[must_use]
        const fn without(self, p: Param) -> ParamSet {
            ParamSet(self.0 & !(1 << p as u32))
        }
    }

    /// Adds `p`.
    pub(crate) fn insert(&mut self, p: Param) {
        *self = self.with(p);
    }

    /// Removes `p`.
    pub(crate) fn remove(&mut self, p: Param) {
        *self = self.without(p);
    }

    /// The parameters in both sets.
    #[must_use]
    pub(crate) const fn intersection(self, other: ParamSet) -> ParamSet {
        ParamSet(self.0 & other.0)
    }

    /// Number of parameters.
    #[cfg(test)]
    pub(crate) const fn len(self) -> usize {
        self.0.count_ones() as usize
    }

    /// True when the set is empty.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    research_pub! {
        /// The parameters in both this set and `other`'s complement.
        #[must_use]
        const fn difference(self, other: ParamSet) -> ParamSet {
            ParamSet(self.0 & !other.0)
        }
    }

    research_pub! {
        /// The parameters in either set.
        #[must_use]
        const fn union(self, other: ParamSet) -> ParamSet {
            ParamSet(self.0 | other.0)
        }
    }

    /// The parameters in vector order (outside the crate: `for p in set`,
    /// the `IntoIterator` impl).
    pub(crate) fn iter(self) -> impl Iterator<Item = Param> {
        Param::ALL.into_iter().filter(move |p| self.contains(*p))
    }

    /// The parameters' names in vector order (as an error states them).
    pub(crate) fn names(self) -> Vec<&'static str> {
        self.iter().map(Param::name).collect()
    }

    /// Vector positions of the parameters, ascending.
    pub(crate) fn indices(self) -> Vec<usize> {
        self.iter().map(Param::index).collect()
    }
}

/// The parameters in vector order.
impl IntoIterator for ParamSet {
    type Item = Param;
    type IntoIter = std::vec::IntoIter<Param>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter().collect::<Vec<_>>().into_iter()
    }
}

impl FromIterator<Param> for ParamSet {
    fn from_iter<I: IntoIterator<Item = Param>>(iter: I) -> Self {
        iter.into_iter().fold(ParamSet::EMPTY, ParamSet::with)
    }
}

impl std::fmt::Display for ParamSet {
    /// Names joined by ", " (`"c_d, t_r, d"`).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (i, p) in self.iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            f.write_str(p.name())?;
        }
        Ok(())
    }
}

impl std::fmt::Debug for ParamSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_set().entries(self.iter()).finish()
    }
}

impl std::str::FromStr for ParamSet {
    type Err = Error;
    /// Comma-separated names (`"c_d,t_r,d"`); the empty string is the empty
    /// set. `lever-arm` (or `lever_arm`) stands for `lever_x, lever_y`, and
    /// `heading-offset` for `heading_offset`.
    fn from_str(s: &str) -> Result<Self> {
        let mut set = ParamSet::EMPTY;
        for n in s.split(',').map(str::trim).filter(|n| !n.is_empty()) {
            set = set.union(match n {
                "lever-arm" | "lever_arm" => ParamSet::LEVER_ARM,
                "heading-offset" => ParamSet::EMPTY.with(Param::HeadingOffset),
                _ => ParamSet::EMPTY.with(n.parse::<Param>()?),
            });
        }
        Ok(set)
    }
}

impl Serialize for ParamSet {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.collect_seq(self.iter())
    }
}

impl<'de> Deserialize<'de> for ParamSet {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        Ok(Vec::<Param>::deserialize(d)?.into_iter().collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_in_json_and_text() {
        let s = ParamSet::THETA.without(Param::CE);
        let j = serde_json::to_string(&s).expect("json");
        assert_eq!(j, r#"["c_d","t_r","d"]"#);
        assert_eq!(serde_json::from_str::<ParamSet>(&j).expect("back"), s);
        assert_eq!(s.to_string(), "c_d, t_r, d");
        assert_eq!("c_d, t_r,d".parse::<ParamSet>().expect("parse"), s);
        assert_eq!(serde_json::to_string(&Param::TR).expect("json"), r#""t_r""#);
        for (i, p) in Param::THETA.into_iter().enumerate() {
            assert_eq!(p.index(), i);
            assert_eq!(Param::from_index(i), Some(p));
            assert_eq!(p.name(), crate::model::THETA_NAMES[i]);
        }
    }

    #[test]
    fn unknown_name_is_a_parse_error_naming_the_choices() {
        let e = "c_e,tr".parse::<ParamSet>().expect_err("tr is not a parameter");
        assert_eq!(
            e.to_string(),
            "invalid parameter 'tr': use c_e, c_d, t_r or d (or lever_x, lever_y, heading_offset)"
        );
    }

    #[test]
    fn extrinsics_names_and_groups() {
        let s: ParamSet = "lever-arm, heading-offset".parse().expect("groups");
        assert_eq!(s, ParamSet::EXTRINSICS);
        assert_eq!(s.to_string(), "lever_x, lever_y, heading_offset");
        assert_eq!("lever_y".parse::<ParamSet>().expect("name"), ParamSet::EMPTY.with(Param::LeverY));
        assert_eq!(serde_json::to_string(&s).expect("json"), r#"["lever_x","lever_y","heading_offset"]"#);
        for (i, p) in Param::ALL.into_iter().enumerate() {
            assert_eq!(p.index(), i);
            assert_eq!(Param::from_index(i), Some(p));
            assert_eq!(p.is_theta(), i < 4);
            assert_eq!(p.extrinsics_index(), i.checked_sub(4));
        }
        assert_eq!(ParamSet::THETA.union(ParamSet::EXTRINSICS).len(), 7);
        assert_eq!(ParamSet::THETA.union(ParamSet::LEVER_ARM).difference(ParamSet::THETA), ParamSet::LEVER_ARM);
        let e = Extrinsics { lever_x: -0.9, lever_y: 0.1, heading_offset: -0.01 };
        approx::assert_relative_eq!(Param::LeverY.value_in(&Theta::PAPER_INITIAL, &e), 0.1);
        approx::assert_relative_eq!(Param::TR.value_in(&Theta::PAPER_INITIAL, &e), 1.6);
    }

    #[test]
    fn set_operations() {
        let mut s = ParamSet::EMPTY;
        assert!(s.is_empty());
        s.insert(Param::D);
        s.insert(Param::CE);
        assert_eq!(s.iter().collect::<Vec<_>>(), vec![Param::CE, Param::D], "vector order");
        assert_eq!(s.len(), 2);
        assert_eq!(s.indices(), vec![0, 3]);
        s.remove(Param::CE);
        assert!(!s.contains(Param::CE) && s.contains(Param::D));
        assert_eq!(ParamSet::THETA.intersection(s), s);
    }
}
