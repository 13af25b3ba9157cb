//! How the values of [`super::Settings`] deserialize: text the way the
//! command line takes it, and the lists, numbers and tables TOML and JSON
//! give. A bad value's message is the library's parser's.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::de::{self, Deserializer, MapAccess, SeqAccess, Visitor};
use serde::Deserialize;

use super::NoiseModelSetting;
use crate::calibrate::eiv::noise_model_from_table;
use crate::calibrate::FinalSegments;
use crate::eiv::NoiseSource;
use crate::error::{Error, Result};
use crate::io::param_file::ParamFile;
use crate::model::param::ParamSet;
use crate::model::{Theta, THETA_NAMES};

/// A value given as text and parsed by the library (`FromStr`): a method,
/// a solver, a quantisation model…
pub(super) fn parsed<'de, D, T>(d: D) -> std::result::Result<Option<T>, D::Error>
where
    D: Deserializer<'de>,
    T: FromStr<Err = Error>,
{
    let text = String::deserialize(d)?;
    text.parse().map(Some).map_err(de::Error::custom)
}

/// Text with commas, or a list of texts, joined with commas.
struct TextOrList(&'static str);

impl<'de> Visitor<'de> for TextOrList {
    type Value = String;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "{} as text with commas or a list of names", self.0)
    }
    fn visit_str<E: de::Error>(self, v: &str) -> std::result::Result<String, E> {
        Ok(v.to_string())
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<String, A::Error> {
        let mut names = Vec::new();
        while let Some(n) = seq.next_element::<String>()? {
            names.push(n);
        }
        Ok(names.join(","))
    }
}

/// Parameters: `"c_d,t_r,d"` or `["c_d", "t_r", "d"]` (also `lever-arm`,
/// `heading-offset`).
pub(super) fn param_set<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<Option<ParamSet>, D::Error> {
    let text = d.deserialize_any(TextOrList("parameters"))?;
    text.parse().map(Some).map_err(de::Error::custom)
}

/// Noise sources: `"heading_white,pose_white"` or a list of names.
pub(super) fn noise_sources<'de, D: Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<Vec<NoiseSource>>, D::Error> {
    let text = d.deserialize_any(TextOrList("noise sources"))?;
    text.split(',').map(|n| n.trim().parse()).collect::<Result<Vec<_>>>().map(Some).map_err(de::Error::custom)
}

/// A count (`batches`, `segment_length`, …): a whole number 0 or more,
/// written without a decimal point or exponent. A float (`1e3`, `50.0`)
/// or a negative number is refused saying a whole number is wanted.
pub(super) fn whole<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<Option<usize>, D::Error> {
    d.deserialize_any(Whole).map(Some)
}

/// The visitor of [`whole`].
struct Whole;

impl Visitor<'_> for Whole {
    type Value = usize;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(WHOLE)
    }
    fn visit_u64<E: de::Error>(self, v: u64) -> std::result::Result<usize, E> {
        usize::try_from(v).map_err(|_| E::custom(format!("{v} is too large for {WHOLE}")))
    }
    fn visit_i64<E: de::Error>(self, v: i64) -> std::result::Result<usize, E> {
        usize::try_from(v).map_err(|_| E::custom(format!("{v} is not {WHOLE}")))
    }
    fn visit_f64<E: de::Error>(self, v: f64) -> std::result::Result<usize, E> {
        let shown = crate::model::limits::echo_num(v);
        if v.fract() == 0.0 && (0.0..9.007_199_254_740_992e15).contains(&v) {
            return Err(E::custom(format!(
                "{shown} is written as a float (with a decimal point or an exponent): {WHOLE} is wanted, \
                 write it as {v:.0}"
            )));
        }
        Err(E::custom(format!("{shown} is not {WHOLE}")))
    }
}

/// What a count is, for messages.
const WHOLE: &str = "a whole number (0, 1, 2, …)";

/// `"all"`, a number of segments, or that number as text.
pub(super) fn final_segments<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<Option<FinalSegments>, D::Error> {
    struct V;
    impl Visitor<'_> for V {
        type Value = FinalSegments;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("\"all\" or a number of segments")
        }
        fn visit_str<E: de::Error>(self, v: &str) -> std::result::Result<FinalSegments, E> {
            v.parse().map_err(E::custom)
        }
        fn visit_u64<E: de::Error>(self, v: u64) -> std::result::Result<FinalSegments, E> {
            usize::try_from(v).map(FinalSegments::Random).map_err(E::custom)
        }
        fn visit_i64<E: de::Error>(self, v: i64) -> std::result::Result<FinalSegments, E> {
            usize::try_from(v)
                .map(FinalSegments::Random)
                .map_err(|_| E::invalid_value(de::Unexpected::Signed(v), &self))
        }
        fn visit_f64<E: de::Error>(self, v: f64) -> std::result::Result<FinalSegments, E> {
            Whole.visit_f64(v).map(FinalSegments::Random)
        }
    }
    d.deserialize_any(V).map(Some)
}

/// A noise model: the path of a noise-model file, or a table of its fields.
pub(super) fn noise_model<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<Option<NoiseModelSetting>, D::Error> {
    struct V;
    impl<'de> Visitor<'de> for V {
        type Value = NoiseModelSetting;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("the path of a noise-model file or a table of noise-model fields")
        }
        fn visit_str<E: de::Error>(self, v: &str) -> std::result::Result<NoiseModelSetting, E> {
            Ok(NoiseModelSetting::File(PathBuf::from(v)))
        }
        fn visit_map<A: MapAccess<'de>>(self, map: A) -> std::result::Result<NoiseModelSetting, A::Error> {
            let table = toml::Table::deserialize(de::value::MapAccessDeserializer::new(map))?;
            noise_model_from_table(table).map(NoiseModelSetting::Stated).map_err(de::Error::custom)
        }
    }
    d.deserialize_any(V).map(Some)
}

/// θ from text: `"c_e,c_d,t_r,d"` (checked) or the path of a parameter file.
fn theta_from_text(v: &str) -> Result<Theta> {
    let path = Path::new(v);
    if ParamFile::is_param_file(path) {
        // `read` has checked θ.
        return ParamFile::read(path, None)?.theta();
    }
    v.parse().map_err(|e| ParamFile::named_file_error(v, e))
}

/// θ from four numbers, checked as `--theta` is.
fn theta_from_numbers(v: &[f64]) -> Result<Theta> {
    let [c_e, c_d, t_r, d] = v[..] else {
        return Err(Error::InvalidTheta(crate::io::exact::count_message(4, crate::io::exact::THETA_VALUES, v.len())));
    };
    let theta = Theta { c_e, c_d, t_r, d };
    crate::model::limits::check_theta(&theta)?;
    Ok(theta)
}

/// The forms θ takes, for messages.
const THETA_FORMS: &str = "θ as \"c_e,c_d,t_r,d\", four numbers, a table {c_e, c_d, t_r, d} or a parameter file";

/// θ as `"c_e,c_d,t_r,d"`, four numbers, a table of the four, or the path
/// of a parameter file.
struct ThetaVisitor;

impl<'de> Visitor<'de> for ThetaVisitor {
    type Value = Theta;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(THETA_FORMS)
    }
    fn visit_str<E: de::Error>(self, v: &str) -> std::result::Result<Theta, E> {
        theta_from_text(v).map_err(E::custom)
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<Theta, A::Error> {
        let mut v = Vec::with_capacity(4);
        while let Some(x) = seq.next_element::<f64>()? {
            v.push(x);
        }
        theta_from_numbers(&v).map_err(de::Error::custom)
    }
    fn visit_map<A: MapAccess<'de>>(self, map: A) -> std::result::Result<Theta, A::Error> {
        let fields = BTreeMap::<String, f64>::deserialize(de::value::MapAccessDeserializer::new(map))?;
        theta_from_fields(&fields).map_err(de::Error::custom)
    }
}

/// θ from a table of its four parameters, checked as `--theta` is: a key
/// other than `c_e`, `c_d`, `t_r`, `d` (a typo such as `ce`) is refused,
/// naming it, as is a missing one.
fn theta_from_fields(fields: &BTreeMap<String, f64>) -> Result<Theta> {
    if let Some(k) = fields.keys().find(|k| !THETA_NAMES.contains(&k.as_str())) {
        return Err(Error::InvalidTheta(format!("unknown key '{}': θ has c_e, c_d, t_r and d", crate::drive::echo(k))));
    }
    let missing: Vec<&str> = THETA_NAMES.iter().copied().filter(|n| !fields.contains_key(*n)).collect();
    if !missing.is_empty() {
        return Err(Error::InvalidTheta(format!("missing {}: θ has c_e, c_d, t_r and d", missing.join(", "))));
    }
    theta_from_numbers(&THETA_NAMES.map(|n| fields[n]))
}

/// θ_0 in any of the forms of [`ThetaVisitor`].
pub(super) fn theta<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<Option<Theta>, D::Error> {
    d.deserialize_any(ThetaVisitor).map(Some)
}

/// θ from JSON in the forms the `theta0` setting, `--theta` and Python's
/// θ arguments take (`"c_e,c_d,t_r,d"`, four numbers, an object of the
/// four, or the path of a parameter file), each checked as `--theta` is
/// (finite, within the physical limits of
/// [`Theta::check_physical_limits`]; an object's key other than the four
/// is refused).
///
/// # Errors
/// [`Error::InvalidTheta`] for a value of another form, else the parser's
/// or the check's error.
impl TryFrom<serde_json::Value> for Theta {
    type Error = Error;
    fn try_from(value: serde_json::Value) -> Result<Theta> {
        let bad = |e: serde_json::Error| Error::InvalidTheta(format!("{e}; give {THETA_FORMS}"));
        Ok(match value {
            serde_json::Value::String(s) => theta_from_text(&s)?,
            v @ serde_json::Value::Array(_) => {
                theta_from_numbers(&serde_json::from_value::<Vec<f64>>(v).map_err(bad)?)?
            }
            v @ serde_json::Value::Object(_) => {
                theta_from_fields(&serde_json::from_value::<BTreeMap<String, f64>>(v).map_err(bad)?)?
            }
            v => return Err(Error::InvalidTheta(format!("{v}: give {THETA_FORMS}"))),
        })
    }
}

/// A seed: an integer 0 … 2⁶⁴ − 1 (`seed`, `bootstrap_seed`). Anything
/// else (a negative number, a fraction, a number beyond 2⁶⁴ − 1 that JSON
/// carries as a float) is refused saying so.
pub(super) fn seed<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<Option<u64>, D::Error> {
    struct V;
    impl Visitor<'_> for V {
        type Value = u64;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str(SEED_RANGE)
        }
        fn visit_u64<E: de::Error>(self, v: u64) -> std::result::Result<u64, E> {
            Ok(v)
        }
        fn visit_i64<E: de::Error>(self, v: i64) -> std::result::Result<u64, E> {
            u64::try_from(v).map_err(|_| E::custom(format!("{v} is not {SEED_RANGE}")))
        }
        fn visit_f64<E: de::Error>(self, v: f64) -> std::result::Result<u64, E> {
            Err(E::custom(format!("{} is not {SEED_RANGE}", crate::model::limits::echo_num(v))))
        }
    }
    d.deserialize_any(V).map(Some)
}

/// What a seed is, for messages.
const SEED_RANGE: &str = "a seed, an integer 0 … 2^64 − 1 (18446744073709551615)";
