//! Parameter files out and back in: the calibrated parameters as a ROS 2
//! parameter file (YAML, `ros__parameters` layout) or JSON, with their 1σ,
//! units, the verdict and provenance, so a robot stack can load them
//! directly; [`ParamFile::read`] reads them back (a θ for validation or a
//! new start).
//!
//! Under odocal's own names the file holds, for node `odocal` (configurable):
//!
//! ```yaml
//! odocal:
//!   ros__parameters:
//!     c_e: 1.951448          # m, effective rear wheel circumference
//!     c_e_sigma: 2.1e-05
//!     ...
//!     verdict: "accepted"
//!     provenance:
//!       input: "drive.csv"
//!       method: "batch-gn"
//!       odocal_version: "0.1.0"
//!       date: "2026-11-23"
//!       fingerprint: "6466b844…"  # the drives' Drive::fingerprint (odocal calibrate, Python)
//! ```
//!
//! With [`ParamMapping::DiffDriveController`] the wheel parameters are also
//! written under the keys of ROS 2 `diff_drive_controller`:
//! `wheel_separation` = t_r, `wheel_radius` = c_e / 2π,
//! `left_wheel_radius_multiplier` = (c_e + c_d/2) / c_e and
//! `right_wheel_radius_multiplier` = (c_e − c_d/2) / c_e (d, the load
//! transfer, has no counterpart there and is only under odocal's name). The
//! radius is physical only when one model revolution is one wheel revolution
//! (wheel speeds in rev/s or rad/s, or ticks with `ticks_per_rev` the true
//! encoder resolution).

use std::fmt::Write as _;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::model::param::ParamSet;
use crate::model::{Theta, THETA_NAMES};

mod extrinsics;

/// Onto which consumer's keys the parameters are also written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ParamMapping {
    /// odocal's own names only (default).
    #[default]
    Odocal,
    /// Also ROS 2 `diff_drive_controller`'s keys.
    DiffDriveController,
}

impl std::str::FromStr for ParamMapping {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "odocal" => Ok(ParamMapping::Odocal),
            "diff_drive_controller" | "diff-drive-controller" => Ok(ParamMapping::DiffDriveController),
            _ => Err(Error::InvalidOption {
                field: "params_mapping",
                reason: format!("'{s}': use odocal or diff_drive_controller"),
            }),
        }
    }
}

/// One parameter of the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct ParamEntry {
    /// Name (`c_e`, …).
    pub name: String,
    /// Value, SI.
    pub value: f64,
    /// 1σ, SI; `None` when the parameter was held.
    pub sigma: Option<f64>,
    /// SI unit.
    pub unit: String,
    /// What it is.
    pub description: String,
    /// Named not observable from the calibration's data: its value is the
    /// start's and its σ is no measure of it (`<name>_observable: false`).
    #[serde(default)]
    pub not_observable: bool,
}

/// The content of a parameter file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParamFile {
    /// ROS node name the parameters belong to. Default `odocal`.
    pub node: String,
    /// The parameters.
    pub(crate) params: Vec<ParamEntry>,
    /// The verdict (`accepted`, `doubtful`, `rejected`), when there is one.
    pub verdict: Option<String>,
    /// Reasons for the verdict.
    pub verdict_reasons: Vec<String>,
    /// Provenance: input, method, odocal version, date (key–value).
    pub provenance: Vec<(String, String)>,
    /// Extra keys for a consumer.
    pub mapping: ParamMapping,
}

/// What the reference extrinsics' σ in a parameter file covers
/// (provenance `extrinsics_sigma_covers`).
pub(crate) const EXTRINSICS_SIGMA_COVERS: &str = "within-drive σ";

const UNITS: [&str; 4] = ["m", "m", "m", "m/(m/s^2)"];
const DESCRIPTIONS: [&str; 4] = [
    "effective rear wheel circumference (per model revolution)",
    "rear wheel circumference difference, left minus right",
    "rear track width",
    "load-transfer coefficient: circumference change per m/s^2 of lateral acceleration",
];

/// θ from the file's `c_e`, `c_d`, `t_r`, `d`, checked for physical sanity.
///
/// # Errors
/// [`Error::InvalidTheta`] when one is missing or the values are absurd.
impl TryFrom<&ParamFile> for Theta {
    type Error = Error;
    fn try_from(file: &ParamFile) -> Result<Theta> {
        file.theta()
    }
}

impl ParamFile {
    /// Whether `path` names a parameter file by its extension (`.yaml`,
    /// `.yml`, `.json`: the files [`ParamFile::text_for`] writes and
    /// [`ParamFile::read`] reads), e.g. to tell one from a θ typed as text.
    pub fn is_param_file(path: &Path) -> bool {
        FileFormat::of(path).is_some()
    }

    /// The error for θ text `s` that is not four numbers: when it names an
    /// existing file, that its name lacks a parameter file's extension,
    /// else `parse_error` as it is.
    pub(crate) fn named_file_error(s: &str, parse_error: Error) -> Error {
        if !Path::new(s).is_file() {
            return parse_error;
        }
        Error::InvalidTheta(format!(
            "'{s}' is a file, but its name does not end in .yaml, .yml or .json, the extensions of a parameter \
             file (a `--params-out` file): give it one of them (e.g. copy it to a .yaml name), or give θ as \
             c_e,c_d,t_r,d (SI units)"
        ))
    }

    /// Today's date (UTC) as `YYYY-MM-DD`, from the system clock: the
    /// `date` of a file [`CalibrationReport::param_file`](crate::CalibrationReport::param_file) writes.
    fn utc_date_today() -> String {
        let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
        let (y, m, d) = civil_from_days((secs / 86_400) as i64);
        format!("{y:04}-{m:02}-{d:02}")
    }

    /// Appends the reference extrinsics (`lever_x`, `lever_y` in m,
    /// `heading_offset` in rad) with their 1σ (`None` for held entries).
    /// Their σ is the one the text, JSON and HTML reports give them: this
    /// drive's cluster-robust σ when computed, else the model σ, not θ's σ
    /// for the next drive; when one is estimated the provenance says so
    /// (`extrinsics_sigma`: `cluster-robust` or `model`,
    /// `extrinsics_sigma_covers`: `within-drive σ`).
    pub(crate) fn add_extrinsics(&mut self, x: &crate::model::extrinsics::ExtrinsicsEstimate) {
        let (value, sd) = (x.value.to_array(), x.result_std_dev().to_array());
        let what = [
            ("m", "pose reference lever arm from the rear-axle centre, forward"),
            ("m", "pose reference lever arm from the rear-axle centre, left"),
            ("rad", "pose reference heading minus vehicle heading"),
        ];
        for (i, p) in crate::model::param::Param::EXTRINSICS.into_iter().enumerate() {
            self.params.push(ParamEntry {
                name: p.name().into(),
                value: value[i],
                sigma: x.free.contains(p).then_some(sd[i]),
                unit: what[i].0.into(),
                description: what[i].1.into(),
                not_observable: false,
            });
        }
        if !x.free.intersection(ParamSet::EXTRINSICS).is_empty() {
            let kind = if x.robust.is_some() { "cluster-robust" } else { "model" };
            self.provenance.push(("extrinsics_sigma".into(), kind.into()));
            self.provenance.push(("extrinsics_sigma_covers".into(), EXTRINSICS_SIGMA_COVERS.into()));
        }
        if !x.per_drive.is_empty() {
            // A joint calibration: heading_offset above is the drives' mean.
            let per: Vec<String> = x
                .per_drive
                .iter()
                .map(|p| format!("drive {}: {:e} ± {:.1e} rad", p.drive + 1, p.value, p.result_std_dev()))
                .collect();
            self.provenance.push(("heading_offset_per_drive".into(), per.join("; ")));
            if let Some(e) = self.params.iter_mut().find(|e| e.name == "heading_offset") {
                e.description = "pose reference heading minus vehicle heading, mean of the drives' own".into();
            }
        }
    }

    /// A file for θ with 1σ per entry (`None` = held), provenance filled with
    /// `input`, `method`, the odocal version and today's UTC date.
    pub fn from_theta(theta: &Theta, sigma: [Option<f64>; 4], input: &str, method: &str) -> ParamFile {
        let params = (0..4)
            .map(|i| ParamEntry {
                name: THETA_NAMES[i].into(),
                value: theta.to_array()[i],
                sigma: sigma[i],
                unit: UNITS[i].into(),
                description: DESCRIPTIONS[i].into(),
                not_observable: false,
            })
            .collect();
        ParamFile {
            node: "odocal".into(),
            params,
            verdict: None,
            verdict_reasons: Vec::new(),
            provenance: vec![
                ("input".into(), input.into()),
                ("method".into(), method.into()),
                ("odocal_version".into(), env!("CARGO_PKG_VERSION").into()),
                ("date".into(), ParamFile::utc_date_today()),
            ],
            mapping: ParamMapping::Odocal,
        }
    }

    /// The names of the parameters the calibration named not observable
    /// from its data (`<name>_observable: false`): their value is the
    /// start's and their σ (for θ, mostly the between-drive prior) is no
    /// measure of them.
    #[cfg(test)]
    pub(crate) fn not_observable(&self) -> Vec<&str> {
        self.params.iter().filter(|p| p.not_observable).map(|p| p.name.as_str()).collect()
    }

    /// Marks the parameters of `set` the file holds as not observable.
    pub(crate) fn mark_not_observable(&mut self, set: ParamSet) {
        for p in &mut self.params {
            if set.iter().any(|q| q.name() == p.name) {
                p.not_observable = true;
            }
        }
    }

    fn value(&self, name: &str) -> Option<f64> {
        self.params.iter().find(|p| p.name == name).map(|p| p.value)
    }

    /// The consumer keys of [`ParamFile::mapping`] with their values.
    pub(crate) fn mapped(&self) -> Vec<(&'static str, f64)> {
        match self.mapping {
            ParamMapping::Odocal => Vec::new(),
            ParamMapping::DiffDriveController => {
                let (Some(c_e), Some(c_d), Some(t_r)) = (self.value("c_e"), self.value("c_d"), self.value("t_r"))
                else {
                    return Vec::new();
                };
                vec![
                    ("wheel_separation", t_r),
                    ("wheel_radius", c_e / std::f64::consts::TAU),
                    ("left_wheel_radius_multiplier", (c_e + c_d / 2.0) / c_e),
                    ("right_wheel_radius_multiplier", (c_e - c_d / 2.0) / c_e),
                ]
            }
        }
    }

    /// The ROS 2 parameter file (YAML). Numbers are written in shortest
    /// round-trip form, so reading them back gives the same f64.
    pub(crate) fn to_ros2_yaml(&self) -> String {
        let mut y = String::new();
        let _ = writeln!(y, "# odocal calibration; units: SI (m, m/(m/s^2)); *_sigma = 1 standard deviation");
        let _ = writeln!(y, "{}:", yaml_key(&self.node));
        let _ = writeln!(y, "  ros__parameters:");
        for p in &self.params {
            let _ = writeln!(y, "    {}: {}  # {}, {}", yaml_key(&p.name), yaml_f64(p.value), p.unit, p.description);
            match p.sigma {
                Some(s) => {
                    let _ = writeln!(y, "    {}_sigma: {}", yaml_key(&p.name), yaml_f64(s));
                }
                None => {
                    let _ = writeln!(y, "    {}_held: true", yaml_key(&p.name));
                }
            }
            if p.not_observable {
                let _ = writeln!(
                    y,
                    "    {}_observable: false  # not observable from these data: value and σ not to be trusted",
                    yaml_key(&p.name)
                );
            }
        }
        for (k, v) in self.mapped() {
            let _ = writeln!(y, "    {k}: {}", yaml_f64(v));
        }
        if let Some(v) = &self.verdict {
            let _ = writeln!(y, "    verdict: {}", yaml_str(v));
            // ROS 2 types a parameter by its value, and an empty list has
            // none: rclcpp refuses the file ("No parameter value set"). No
            // reasons is written as no key, as reading takes it.
            if !self.verdict_reasons.is_empty() {
                let reasons: Vec<String> = self.verdict_reasons.iter().map(|r| yaml_str(r)).collect();
                let _ = writeln!(y, "    verdict_reasons: [{}]", reasons.join(", "));
            }
        }
        // An empty map would be a key without a value, which ROS 2 refuses too.
        if !self.provenance.is_empty() {
            let _ = writeln!(y, "    provenance:");
            for (k, v) in &self.provenance {
                let _ = writeln!(y, "      {}: {}", yaml_key(k), yaml_str(v));
            }
        }
        y
    }

    /// The same content as JSON.
    pub fn to_json(&self) -> serde_json::Value {
        let mut params = serde_json::Map::new();
        for p in &self.params {
            params.insert(p.name.clone(), serde_json::json!(p.value));
            match p.sigma {
                Some(s) => params.insert(format!("{}_sigma", p.name), serde_json::json!(s)),
                None => params.insert(format!("{}_held", p.name), serde_json::json!(true)),
            };
            if p.not_observable {
                params.insert(format!("{}_observable", p.name), serde_json::json!(false));
            }
        }
        for (k, v) in self.mapped() {
            params.insert(k.into(), serde_json::json!(v));
        }
        let prov: serde_json::Map<String, serde_json::Value> =
            self.provenance.iter().map(|(k, v)| (k.clone(), serde_json::json!(v))).collect();
        let mut v = serde_json::json!({
            "schema_version": JSON_SCHEMA_VERSION,
            "node": self.node,
            "parameters": params,
            "units": self.params.iter().map(|p| (p.name.clone(), serde_json::json!(p.unit))).collect::<serde_json::Map<_, _>>(),
            "verdict": self.verdict,
            "provenance": prov,
        });
        // The keys of the YAML file: `verdict_reasons` only when there are
        // reasons (an empty list has no ROS 2 type there).
        if self.verdict.is_some() && !self.verdict_reasons.is_empty() {
            v["verdict_reasons"] = serde_json::json!(self.verdict_reasons);
        }
        v
    }

    /// Writes [`ParamFile::text_for`] to `path`, atomically.
    #[cfg(test)]
    pub(crate) fn write(&self, path: &Path) -> Result<()> {
        crate::output::write_text(path, &self.text_for(path)?)
    }

    /// Checks `name` as the node of a parameter file (the CLI's
    /// `--params-node`, Python's `write_params(node=)`): letters, digits
    /// and `_`, with `/` for a namespace and `*` for ROS 2's wildcards
    /// (`/**`). ROS 2 loads no file whose node is empty or holds other
    /// characters (`my-node`, a space), so a write would be wasted.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] (field `node`) saying what to give.
    pub fn check_node_name(name: &str) -> Result<()> {
        let fits = |c: char| c.is_ascii_alphanumeric() || matches!(c, '_' | '/' | '*');
        if name.is_empty() || !name.chars().all(fits) {
            return Err(Error::InvalidOption {
                field: "node",
                reason: format!(
                    "'{}' is not a ROS 2 node name: give letters, digits and _ (with / for a namespace), e.g. \
                     odocal or /vehicle/odometry",
                    name.escape_debug()
                ),
            });
        }
        Ok(())
    }

    /// The text of the parameter file at `path`: the ROS 2 parameter file
    /// (YAML) for a `.yaml`/`.yml` path and for `-` (stdout, where a front
    /// end writes it), JSON for `.json`. Numbers are written in shortest
    /// round-trip form, so reading them back gives the same f64. Write it
    /// with [`crate::output::write_text`] (atomically), or with a front
    /// end's other outputs as one ([`crate::output::write_texts`]).
    ///
    /// ```
    /// use odocal::{ParamFile, Theta};
    /// let dir = tempfile::tempdir()?;
    /// let path = dir.path().join("odocal.yaml");
    /// let f = ParamFile::from_theta(&Theta::PAPER_NOMINAL, [None; 4], "drive.csv", "eiv");
    /// odocal::output::write_text(&path, &f.text_for(&path)?)?;
    /// assert_eq!(ParamFile::read(&path, None)?.node, f.node);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// # Errors
    /// [`Error::ParamFile`] naming the path for another extension or for
    /// values [`ParamFile::read`] would refuse (a value or σ not finite, a
    /// negative σ, θ or the extrinsics outside their physical limits);
    /// [`Error::InvalidOption`] for a node that is no ROS 2 node name
    /// ([`ParamFile::check_node_name`]).
    pub fn text_for(&self, path: &Path) -> Result<String> {
        ParamFile::check_node_name(&self.node)?;
        let bad = |reason: String| Error::ParamFile { path: path.to_path_buf(), reason };
        self.check_values().map_err(|r| bad(format!("not written, it would not read back: {r}")))?;
        if crate::output::is_stdout(path) {
            return Ok(self.to_ros2_yaml());
        }
        Ok(match FileFormat::of(path) {
            Some(FileFormat::Yaml) => self.to_ros2_yaml(),
            Some(FileFormat::Json) => {
                let mut s = serde_json::to_string_pretty(&self.to_json())
                    .map_err(|source| Error::Json { context: path.display().to_string(), source })?;
                s.push('\n');
                s
            }
            None => return Err(bad("the file name says the format: use a .yaml, .yml or .json file name".into())),
        })
    }
}

/// A parameter file's format, by its extension.
#[derive(Clone, Copy)]
enum FileFormat {
    /// `.yaml`, `.yml`: a ROS 2 parameter file.
    Yaml,
    /// `.json`.
    Json,
}

impl FileFormat {
    fn of(path: &Path) -> Option<FileFormat> {
        let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("yaml" | "yml") => Some(FileFormat::Yaml),
            Some("json") => Some(FileFormat::Json),
            _ => None,
        }
    }
}

/// Largest parameter file [`ParamFile::read`] accepts, bytes (odocal writes
/// about 1.5 kB).
pub(crate) const MAX_PARAM_FILE_BYTES: u64 = 1 << 20;

/// A value of the flat `ros__parameters` / `parameters` map.
enum Flat {
    Number(f64),
    Bool(bool),
    Text(String),
    Other(&'static str),
}

impl Flat {
    /// What the value is, for a message.
    fn describe(&self) -> String {
        match self {
            Flat::Number(x) => format!("the number {x}"),
            Flat::Bool(b) => format!("{b}"),
            Flat::Text(t) => format!("the text '{}'", crate::drive::echo(t)),
            Flat::Other(what) => (*what).to_string(),
        }
    }
}

/// The extrinsics' names, units and descriptions, in [`Param::EXTRINSICS`] order.
const EXTRINSIC_INFO: [(&str, &str, &str); 3] = [
    ("lever_x", "m", "pose reference lever arm from the rear-axle centre, forward"),
    ("lever_y", "m", "pose reference lever arm from the rear-axle centre, left"),
    ("heading_offset", "rad", "pose reference heading minus vehicle heading"),
];

impl ParamFile {
    /// Reads a parameter file as [`ParamFile::text_for`] writes it (and as a
    /// user may edit it): a ROS 2 parameter file (`.yaml`/`.yml`: the node
    /// whose `ros__parameters` hold `c_e`, or the only node) or odocal's JSON
    /// (`.json`). `c_e`, `c_d`, `t_r` and `d` are required (SI units, checked
    /// like a typed θ); `<name>_sigma` gives a 1σ, `<name>_held: true` marks
    /// a held parameter, `<name>_observable: false` one the calibration
    /// named not observable; `lever_x`, `lever_y`, `heading_offset`, the verdict
    /// and the provenance are read when present; other keys (a consumer's,
    /// e.g. `wheel_separation`) are ignored. Writing the result again gives
    /// the same parameters to the bit. `node` names the ROS 2 node to read
    /// (a parameter file may hold several nodes' parameters); `None` takes
    /// the one node with odocal's parameters.
    ///
    /// ```
    /// use odocal::ParamFile;
    /// use odocal::Theta;
    /// let dir = std::env::temp_dir().join(format!("odocal-doc-{}", std::process::id()));
    /// std::fs::create_dir_all(&dir)?;
    /// let path = dir.join("odocal.yaml");
    /// let theta = Theta { c_e: 1.951448, c_d: -0.0021, t_r: 1.5649, d: 0.0008 };
    /// let f = ParamFile::from_theta(&theta, [Some(2.1e-5), None, Some(3e-3), Some(1e-4)], "drive.csv", "eiv");
    /// odocal::output::write_text(&path, &f.text_for(&path)?)?;
    /// let back = ParamFile::read(&path, None)?;
    /// assert_eq!(Theta::try_from(&back)?, theta);
    /// # std::fs::remove_dir_all(&dir)?;
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// # Errors
    /// [`Error::Io`]; [`Error::ParamFile`] naming the key for a file that is
    /// not a parameter file (another extension, larger than
    /// `MAX_PARAM_FILE_BYTES`, not YAML/JSON, a required parameter missing
    /// or not a number, a physically absurd θ); when `node` is not in the
    /// file, or when it is `None` and several nodes (or YAML documents)
    /// hold odocal's parameters.
    pub fn read(path: impl AsRef<Path>, node: Option<&str>) -> Result<ParamFile> {
        let path = path.as_ref();
        let bad = |reason: String| Error::ParamFile { path: path.to_path_buf(), reason };
        let Some(format) = FileFormat::of(path) else {
            return Err(bad("not a parameter file: use the .yaml, .yml or .json file `--params-out` wrote".into()));
        };
        let text = crate::output::limited::read_text_limited(path, MAX_PARAM_FILE_BYTES, "a parameter file").map_err(
            |source| match source.kind() {
                std::io::ErrorKind::InvalidData | std::io::ErrorKind::InvalidInput => {
                    bad(format!("{source} (odocal writes about 1.5 kB)"))
                }
                _ => Error::io(path, source),
            },
        )?;
        let (node, flat) = match format {
            FileFormat::Yaml => flat_yaml(&text, node),
            FileFormat::Json => flat_json(&text).and_then(|(n, flat)| match node {
                Some(want) if want != n => Err(format!(
                    "no node `{}` (the file's node is `{}`)",
                    crate::drive::echo(want),
                    crate::drive::echo(&n)
                )),
                _ => Ok((n, flat)),
            }),
        }
        .map_err(bad)?;
        Self::from_flat(node, flat).map_err(bad)
    }

    /// θ from the file's `c_e`, `c_d`, `t_r`, `d`, checked for physical
    /// sanity (outside the crate: `Theta::try_from(&file)`).
    pub(crate) fn theta(&self) -> Result<Theta> {
        let mut v = [0.0; 4];
        for (i, name) in THETA_NAMES.iter().enumerate() {
            v[i] = self.value(name).ok_or_else(|| Error::InvalidTheta(format!("no `{name}` in the parameter file")))?;
        }
        let theta = Theta::from_array(v);
        crate::model::limits::check_theta(&theta)?;
        Ok(theta)
    }

    /// Builds the file from the flat key–value map of one node.
    fn from_flat(node: String, flat: Vec<(String, Flat)>) -> std::result::Result<ParamFile, String> {
        let get = |k: &str| flat.iter().find(|(n, _)| n == k).map(|(_, v)| v);
        let number = |k: &str| -> std::result::Result<Option<f64>, String> {
            match get(k) {
                None => Ok(None),
                Some(Flat::Number(x)) if x.is_finite() => Ok(Some(*x)),
                Some(Flat::Number(x)) => Err(format!("key `{k}`: {x} is not a finite number")),
                Some(Flat::Text(t)) => Err(format!("key `{k}`: '{}' is not a number", crate::drive::echo(t))),
                Some(Flat::Bool(b)) => Err(format!("key `{k}`: {b} is not a number")),
                Some(Flat::Other(what)) => Err(format!("key `{k}`: {what}, not a number")),
            }
        };
        let mut params = Vec::new();
        let names = THETA_NAMES.iter().enumerate().map(|(i, n)| (*n, UNITS[i], DESCRIPTIONS[i], true));
        let extr = EXTRINSIC_INFO.iter().map(|(n, u, d)| (*n, *u, *d, false));
        for (name, unit, description, required) in names.chain(extr) {
            let Some(value) = number(name)? else {
                if required {
                    let found: Vec<&str> = flat.iter().map(|(n, _)| n.as_str()).take(12).collect();
                    return Err(format!(
                        "node `{node}`: no `{name}` (a parameter file needs c_e, c_d, t_r and d, SI units; keys found: {})",
                        if found.is_empty() { "none".to_string() } else { found.join(", ") }
                    ));
                }
                continue;
            };
            let sigma = number(&format!("{name}_sigma"))?;
            if let Some(s) = sigma.filter(|s| *s < 0.0) {
                return Err(format!("key `{name}_sigma`: {s} is negative"));
            }
            if let Some(held) = get(&format!("{name}_held")).filter(|v| !matches!(v, Flat::Bool(_))) {
                return Err(format!("key `{name}_held`: {}, not true or false", held.describe()));
            }
            let not_observable = match get(&format!("{name}_observable")) {
                None | Some(Flat::Bool(true)) => false,
                Some(Flat::Bool(false)) => true,
                Some(_) => return Err(format!("key `{name}_observable`: not true or false")),
            };
            params.push(ParamEntry {
                name: name.into(),
                value,
                sigma,
                unit: unit.into(),
                description: description.into(),
                not_observable,
            });
        }
        let text = |k: &str| match get(k) {
            Some(Flat::Text(t)) => Some(t.clone()),
            _ => None,
        };
        for (k, v) in &flat {
            let text = matches!(v, Flat::Text(_));
            match k.split(['[', '.']).next() {
                Some("verdict") if !(k == "verdict" && text) => {
                    return Err(format!("key `{k}`: {}; `verdict` is text", v.describe()));
                }
                Some("verdict_reasons") if !(k.starts_with("verdict_reasons[") && text) => {
                    return Err(format!("key `{k}`: {}; `verdict_reasons` is a list of texts", v.describe()));
                }
                _ => {}
            }
        }
        let verdict = text("verdict");
        let verdict_reasons = flat
            .iter()
            .filter_map(|(n, v)| match v {
                Flat::Text(t) if n.starts_with("verdict_reasons[") => Some(t.clone()),
                _ => None,
            })
            .collect();
        let provenance = flat
            .iter()
            .filter_map(|(n, v)| match v {
                Flat::Text(t) => n.strip_prefix("provenance.").map(|k| (k.to_string(), t.clone())),
                _ => None,
            })
            .collect();
        let mapping =
            if get("wheel_separation").is_some() { ParamMapping::DiffDriveController } else { ParamMapping::Odocal };
        let f = ParamFile { node, params, verdict, verdict_reasons, provenance, mapping };
        f.check_values()?;
        Ok(f)
    }

    /// The rules [`ParamFile::read`] holds a file's values to, which
    /// [`ParamFile::text_for`] holds them to too: every value and σ a finite
    /// number, no σ negative, θ within the physical limits
    /// ([`Theta::check_physical_limits`]), the extrinsics within theirs.
    fn check_values(&self) -> std::result::Result<(), String> {
        for p in &self.params {
            if !p.value.is_finite() {
                return Err(format!("key `{}`: {} is not a finite number", p.name, p.value));
            }
            match p.sigma {
                Some(s) if !s.is_finite() => return Err(format!("key `{}_sigma`: {s} is not a finite number", p.name)),
                Some(s) if s < 0.0 => return Err(format!("key `{}_sigma`: {s} is negative", p.name)),
                _ => {}
            }
        }
        self.theta().map_err(|e| e.to_string())?;
        crate::model::limits::check_extrinsics(&self.extrinsics().0).map_err(|(k, r)| format!("key `{k}`: {r}"))
    }
}

/// The node and its flattened `ros__parameters` of a ROS 2 parameter file:
/// nested maps as `a.b`, list items as `a[i]`. The node is `want` when
/// given; else the one node whose parameters have `c_e` (or the only node),
/// and several such nodes, or several YAML documents, are refused.
fn flat_yaml(text: &str, want: Option<&str>) -> std::result::Result<(String, Vec<(String, Flat)>), String> {
    use yaml_rust2::Yaml;
    refuse_aliases(text)?;
    let docs = yaml_rust2::YamlLoader::load_from_str(text).map_err(|e| format!("not YAML: {e}"))?;
    let pick =
        "give the node to read (CLI: validate --params-node NAME, calibrate --theta0-node NAME; Python: params_node=)";
    if docs.len() > 1 && want.is_none() {
        return Err(format!("{} YAML documents (`---`): a parameter file holds one; {pick}", docs.len()));
    }
    let mut found = Vec::new();
    for doc in &docs {
        let Yaml::Hash(nodes) = doc else {
            return Err("not a ROS 2 parameter file (expected `NODE:` then `ros__parameters:`)".into());
        };
        for (k, v) in nodes {
            let name = match k {
                Yaml::String(s) => s.clone(),
                other => format!("{other:?}"),
            };
            if let Yaml::Hash(h) = &v["ros__parameters"] {
                found.push((name, h));
            }
        }
    }
    let names = |f: &[(String, &yaml_rust2::yaml::Hash)]| {
        f.iter().map(|(n, _)| crate::drive::echo(n)).collect::<Vec<_>>().join(", ")
    };
    let has_c_e = |h: &&yaml_rust2::yaml::Hash| h.contains_key(&Yaml::String("c_e".into()));
    let chosen = if let Some(want) = want {
        let mut hits: Vec<usize> = (0..found.len()).filter(|&i| found[i].0 == want).collect();
        match hits.len() {
            1 => found.swap_remove(hits.remove(0)),
            0 => return Err(format!("no node `{}` (nodes: {})", crate::drive::echo(want), names(&found))),
            n => return Err(format!("node `{}` appears {n} times", crate::drive::echo(want))),
        }
    } else {
        let with_c_e: Vec<usize> = (0..found.len()).filter(|&i| has_c_e(&found[i].1)).collect();
        match (with_c_e.len(), found.len()) {
            (1, _) => found.swap_remove(with_c_e[0]),
            (0, 1) => found.swap_remove(0),
            (0, 0) => return Err("not a ROS 2 parameter file: no node with `ros__parameters`".into()),
            (0, _) => return Err(format!("no node's `ros__parameters` has `c_e` (nodes: {})", names(&found))),
            _ => {
                let both: Vec<_> = with_c_e.iter().map(|&i| (found[i].0.clone(), found[i].1)).collect();
                return Err(format!("several nodes hold odocal's parameters ({}); {pick}", names(&both)));
            }
        }
    };
    fn walk(prefix: &str, y: &Yaml, out: &mut Vec<(String, Flat)>) {
        match y {
            Yaml::Real(_) | Yaml::Integer(_) => out.push((
                prefix.into(),
                Flat::Number(y.as_f64().or_else(|| y.as_i64().map(|i| i as f64)).unwrap_or(f64::NAN)),
            )),
            Yaml::Boolean(b) => out.push((prefix.into(), Flat::Bool(*b))),
            Yaml::String(s) => out.push((prefix.into(), Flat::Text(s.clone()))),
            Yaml::Array(a) => {
                for (i, v) in a.iter().enumerate() {
                    walk(&format!("{prefix}[{i}]"), v, out);
                }
            }
            Yaml::Hash(h) => {
                for (k, v) in h {
                    if let Yaml::String(k) = k {
                        walk(&format!("{prefix}.{k}"), v, out);
                    }
                }
            }
            Yaml::Null => out.push((prefix.into(), Flat::Other("empty"))),
            _ => out.push((prefix.into(), Flat::Other("not a value"))),
        }
    }
    let mut out = Vec::new();
    for (k, v) in chosen.1 {
        if let Yaml::String(k) = k {
            walk(k, v, &mut out);
        }
    }
    Ok((chosen.0, out))
}

/// Refuses YAML aliases (`*name`) before the document is built: a loader
/// copies the anchored node at every alias, so a few hundred bytes of
/// nested aliases expand to gigabytes. odocal's parameter files have none.
fn refuse_aliases(text: &str) -> std::result::Result<(), String> {
    use yaml_rust2::parser::{Event, Parser};
    let mut parser = Parser::new_from_str(text);
    loop {
        match parser.next_token() {
            Ok((Event::StreamEnd, _)) => return Ok(()),
            Ok((Event::Alias(_), mark)) => {
                return Err(format!(
                    "line {}: a YAML alias (`*name`); a parameter file holds plain values, without anchors \
                     and aliases",
                    mark.line()
                ))
            }
            Ok(_) => {}
            Err(e) => return Err(format!("not YAML: {e}")),
        }
    }
}

/// The `schema_version` of the JSON parameter files odocal writes and reads.
const JSON_SCHEMA_VERSION: u64 = 1;

/// The node and its flattened `parameters` of odocal's JSON parameter file
/// (verdict, reasons and provenance under the same names as in YAML). A
/// file of another `schema_version` (a newer odocal's) is refused: its keys
/// may mean something else; one without (hand-written) is read.
fn flat_json(text: &str) -> std::result::Result<(String, Vec<(String, Flat)>), String> {
    use serde_json::Value;
    let v = serde_json::from_str::<NoDuplicateKeys>(text).map_err(|e| format!("not JSON: {e}"))?.0;
    match v.get("schema_version") {
        None => {}
        Some(x) if x.as_u64() == Some(JSON_SCHEMA_VERSION) => {}
        Some(x) => {
            let x = crate::drive::echo(&x.to_string());
            return Err(format!(
                "schema_version {x}: odocal {} reads parameter files of schema_version {JSON_SCHEMA_VERSION}; \
                 update odocal to read this file (a newer odocal wrote it?)",
                env!("CARGO_PKG_VERSION")
            ));
        }
    }
    let Some(params) = v.get("parameters").and_then(Value::as_object) else {
        let hint = if v.get("theta").is_some() {
            " — a `calibrate --json` report? Write the parameter file with `--params-out FILE.yaml`"
        } else {
            ""
        };
        return Err(format!("not an odocal parameter file (no `parameters` object){hint}"));
    };
    let node = v.get("node").and_then(Value::as_str).unwrap_or("odocal").to_string();
    let flat_of = |x: &Value| match x {
        Value::Number(n) => Flat::Number(n.as_f64().unwrap_or(f64::NAN)),
        Value::Bool(b) => Flat::Bool(*b),
        Value::String(s) => Flat::Text(s.clone()),
        Value::Null => Flat::Other("null"),
        _ => Flat::Other("not a value"),
    };
    let mut out: Vec<(String, Flat)> = params.iter().map(|(k, x)| (k.clone(), flat_of(x))).collect();
    if let Some(x) = v.get("verdict") {
        out.push(("verdict".into(), flat_of(x)));
    }
    match v.get("verdict_reasons") {
        None => {}
        Some(Value::Array(a)) => {
            out.extend(a.iter().enumerate().map(|(i, x)| (format!("verdict_reasons[{i}]"), flat_of(x))))
        }
        Some(_) => return Err("key `verdict_reasons`: not a list; `verdict_reasons` is a list of texts".into()),
    }
    if let Some(o) = v.get("provenance").and_then(Value::as_object) {
        out.extend(o.iter().map(|(k, x)| (format!("provenance.{k}"), flat_of(x))));
    }
    Ok((node, out))
}

/// A JSON value whose objects have no key twice. `serde_json::Value` keeps
/// the last of repeated keys; in a parameter file the first `c_e` and the
/// second cannot both be meant, so the reader refuses the file instead
/// (the YAML reader refuses repeated keys too).
struct NoDuplicateKeys(serde_json::Value);

impl<'de> serde::Deserialize<'de> for NoDuplicateKeys {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        d.deserialize_any(NoDuplicateKeysVisitor).map(NoDuplicateKeys)
    }
}

struct NoDuplicateKeysVisitor;

impl<'de> serde::de::Visitor<'de> for NoDuplicateKeysVisitor {
    type Value = serde_json::Value;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON value")
    }
    fn visit_bool<E>(self, b: bool) -> std::result::Result<Self::Value, E> {
        Ok(b.into())
    }
    fn visit_i64<E>(self, x: i64) -> std::result::Result<Self::Value, E> {
        Ok(x.into())
    }
    fn visit_u64<E>(self, x: u64) -> std::result::Result<Self::Value, E> {
        Ok(x.into())
    }
    fn visit_f64<E>(self, x: f64) -> std::result::Result<Self::Value, E> {
        Ok(serde_json::Number::from_f64(x).map_or(serde_json::Value::Null, serde_json::Value::Number))
    }
    fn visit_str<E>(self, t: &str) -> std::result::Result<Self::Value, E> {
        Ok(t.into())
    }
    fn visit_unit<E>(self) -> std::result::Result<Self::Value, E> {
        Ok(serde_json::Value::Null)
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> std::result::Result<Self::Value, A::Error> {
        let mut out = Vec::new();
        while let Some(NoDuplicateKeys(x)) = seq.next_element()? {
            out.push(x);
        }
        Ok(out.into())
    }
    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> std::result::Result<Self::Value, A::Error> {
        let mut out = serde_json::Map::new();
        while let Some(key) = map.next_key::<String>()? {
            if out.contains_key(&key) {
                let key = crate::drive::echo(&key);
                return Err(serde::de::Error::custom(format!("the key `{key}` twice in one object")));
            }
            let NoDuplicateKeys(x) = map.next_value()?;
            out.insert(key, x);
        }
        Ok(out.into())
    }
}

fn yaml_f64(v: f64) -> String {
    if v.is_finite() {
        let s = format!("{v:?}");
        // `1e-5` is a float in YAML 1.2 but a string in YAML 1.1 readers; write `1.0e-5`.
        match s.split_once('e') {
            Some((m, e)) if !m.contains('.') => format!("{m}.0e{e}"),
            _ => s,
        }
    } else {
        ".nan".into()
    }
}

fn yaml_key(k: &str) -> String {
    if !k.is_empty() && k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/') {
        k.to_string()
    } else {
        yaml_str(k)
    }
}

/// A double-quoted YAML string.
fn yaml_str(s: &str) -> String {
    let mut o = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            '\n' => o.push_str("\\n"),
            // Line and paragraph separators and the BOM: PyYAML refuses them raw.
            c if c.is_control() || matches!(c, '\u{2028}' | '\u{2029}' | '\u{feff}') => {
                let _ = write!(o, "\\u{:04x}", c as u32);
            }
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

/// Proleptic Gregorian date of a day count since 1970-01-01 (H. Hinnant's algorithm).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::extrinsics::Extrinsics;
    use crate::model::param::Param;

    #[test]
    fn a_node_ros_2_cannot_load_is_not_written() {
        for good in ["odocal", "/vehicle/odometry", "/**", "node_2"] {
            ParamFile::check_node_name(good).expect(good);
        }
        let dir = tempfile::tempdir().expect("dir");
        for bad in ["bad node!", "", "a:b", "x\ny", "my-node"] {
            let f = ParamFile { node: bad.into(), ..sample() };
            for name in ["p.yaml", "p.json"] {
                let path = dir.path().join(name);
                let e = f.write(&path).expect_err(bad).to_string();
                assert!(e.starts_with("invalid option `node`: '") && e.contains("is not a ROS 2 node name"), "{e}");
                assert!(!path.exists(), "{bad}: {name} written");
            }
        }
        let e = ParamFile::check_node_name("x\ny").expect_err("newline").to_string();
        assert!(e.contains("'x\\ny'"), "echoed escaped: {e}");
    }

    #[test]
    fn civil_dates() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(20_415), (2025, 11, 23));
        assert_eq!(civil_from_days(11_016), (2000, 2, 29));
    }

    fn sample() -> ParamFile {
        let th = Theta { c_e: 1.951448, c_d: -0.002130942, t_r: 1.564853, d: 0.000396481 };
        let mut f =
            ParamFile::from_theta(&th, [Some(2.1e-5), Some(3e-7), Some(4.7e-5), None], "drive \"a\".csv", "batch-gn");
        f.verdict = Some("accepted".into());
        f.verdict_reasons = vec!["Ē_p 9.3 m < θ_0's 26.9 m".into()];
        f.mapping = ParamMapping::DiffDriveController;
        f
    }

    #[test]
    fn yaml_parses_back_to_the_same_numbers() {
        let f = sample();
        let text = f.to_ros2_yaml();
        let docs = yaml_rust2::YamlLoader::load_from_str(&text).expect("valid YAML");
        let p = &docs[0]["odocal"]["ros__parameters"];
        for e in &f.params {
            assert_eq!(p[e.name.as_str()].as_f64().map(f64::to_bits), Some(e.value.to_bits()), "{}", e.name);
        }
        assert_eq!(p["c_e_sigma"].as_f64(), Some(2.1e-5));
        assert_eq!(p["d_held"].as_bool(), Some(true));
        let sep = p["wheel_separation"].as_f64().expect("mapped");
        assert_eq!(sep.to_bits(), 1.564853f64.to_bits());
        let left = p["left_wheel_radius_multiplier"].as_f64().expect("mapped");
        assert!((left - (1.951448 - 0.002130942 / 2.0) / 1.951448).abs() < 1e-15);
        assert_eq!(p["verdict"].as_str(), Some("accepted"));
        assert_eq!(p["provenance"]["input"].as_str(), Some("drive \"a\".csv"));
        assert_eq!(p["provenance"]["method"].as_str(), Some("batch-gn"));
    }

    fn with_extrinsics(mut f: ParamFile) -> ParamFile {
        use crate::model::extrinsics::ExtrinsicsEstimate;
        f.add_extrinsics(&ExtrinsicsEstimate {
            value: Extrinsics { lever_x: -0.9, lever_y: 0.0, heading_offset: -0.0099 },
            std_dev: Extrinsics { lever_x: 0.01, lever_y: 0.02, heading_offset: 1e-4 },
            free: ParamSet::LEVER_ARM,
            ..ExtrinsicsEstimate::held(Extrinsics::ZERO)
        });
        f
    }

    #[test]
    fn files_read_back_to_the_same_parameters() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = with_extrinsics(sample());
        let yaml = dir.path().join("odocal.yaml");
        f.write(&yaml).expect("write yaml");
        let back = ParamFile::read(&yaml, None).expect("read yaml");
        assert_eq!(back, f);
        assert_eq!(back.to_ros2_yaml(), f.to_ros2_yaml());
        assert_eq!(f.text_for(Path::new("-")).expect("stdout"), f.to_ros2_yaml(), "stdout gets YAML");
        let json = dir.path().join("odocal.json");
        f.write(&json).expect("write json");
        let mut back = ParamFile::read(&json, None).expect("read json");
        // JSON objects are unordered: compare the provenance as a set.
        back.provenance.sort();
        let mut g = f.clone();
        g.provenance.sort();
        assert_eq!(back, g);
        assert_eq!(
            back.theta().expect("theta").to_array().map(f64::to_bits),
            [1.951448, -0.002130942, 1.564853, 0.000396481].map(f64::to_bits)
        );
        let (x, estimated) = back.extrinsics();
        assert_eq!(x, Extrinsics { lever_x: -0.9, lever_y: 0.0, heading_offset: -0.0099 });
        assert_eq!(estimated, ParamSet::LEVER_ARM);
        // On a drive whose manifest states its mount, the estimated lever arm
        // still comes from the file, the held heading offset from the drive.
        let stated = Extrinsics { lever_x: 0.5, lever_y: 0.1, heading_offset: 0.02 };
        let (x, from_file) = back.extrinsics_for_drive(Some(&stated));
        assert_eq!(x, Extrinsics { lever_x: -0.9, lever_y: 0.0, heading_offset: 0.02 });
        assert_eq!(from_file, ["lever_x", "lever_y"]);
        assert_eq!(
            back.extrinsics_for_drive(None),
            (
                Extrinsics { lever_x: -0.9, lever_y: 0.0, heading_offset: -0.0099 },
                vec!["lever_x", "lever_y", "heading_offset"]
            )
        );
    }

    fn read_text(name: &str, text: &str) -> Result<ParamFile> {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join(name);
        std::fs::write(&path, text).expect("write");
        ParamFile::read(&path, None)
    }

    #[test]
    fn hand_written_files_are_read_and_bad_ones_named() {
        // Integers, another node first, keys of a consumer, no σ at all.
        let ok = "/**:\n  ros__parameters:\n    use_sim_time: false\nodocal:\n  ros__parameters:\n    c_e: 1.95\n    \
                  c_d: 0\n    t_r: 1.53\n    d: 0\n    wheel_separation: 1.53\n";
        let f = read_text("p.yaml", ok).expect("hand-written file");
        assert_eq!(f.theta().expect("theta"), Theta { c_e: 1.95, c_d: 0.0, t_r: 1.53, d: 0.0 });
        assert!(f.params.iter().all(|p| p.sigma.is_none()));
        assert_eq!(f.mapping, ParamMapping::DiffDriveController);
        for (name, text, needles) in [
            (
                "p.yaml",
                "odocal:\n  ros__parameters:\n    c_e: 1.95\n    c_d: 0.0\n    d: 0.0\n",
                &["no `t_r`", "keys found: c_e, c_d, d"][..],
            ),
            (
                "p.yaml",
                "odocal:\n  ros__parameters:\n    c_e: big\n    c_d: 0.0\n    t_r: 1.5\n    d: 0.0\n",
                &["key `c_e`", "'big' is not a number"],
            ),
            (
                "p.yaml",
                "odocal:\n  ros__parameters:\n    c_e: 1.95\n    c_d: 0.0\n    t_r: 0.0\n    d: 0.0\n",
                &["t_r"],
            ),
            (
                "p.yaml",
                "odocal:\n  ros__parameters:\n    c_e: 1.95\n    c_e_sigma: -1.0\n",
                &["`c_e_sigma`", "negative"],
            ),
            ("p.yaml", "c_e: 1.95\n", &["no node with `ros__parameters`"]),
            ("p.yaml", "odocal: [unclosed\n", &["not YAML"]),
            ("p.json", "{\"c_e\": 1.95}", &["no `parameters` object"]),
            (
                "p.json",
                "{\"schema_version\": 2, \"parameters\": {\"c_e\": 1.95, \"c_d\": 0, \"t_r\": 1.5, \"d\": 0}}",
                &["schema_version 2", "reads parameter files of schema_version 1", "update odocal"],
            ),
            (
                "p.yaml",
                "odocal:\n  ros__parameters:\n    c_e: 1.0e300\n    c_d: 0.0\n    t_r: 1.5\n    d: 0.0\n",
                &["c_e = 1e300 m is outside 0.05 … 20 m"],
            ),
            ("r.json", "{\"theta\": {\"c_e\": 1.95}}", &["a `calibrate --json` report?", "--params-out"]),
            (
                "p.json",
                "{\"parameters\": {\"c_e\": 1.95, \"c_d\": 0, \"t_r\": 1.5, \"d\": 0, \"c_e\": 3}}",
                &["the key `c_e` twice", "line 1 column"],
            ),
            (
                "p.json",
                "{\"parameters\": {\"c_e\": 1.95, \"c_d\": 0, \"t_r\": 1.5, \"d\": 0, \"c_e_held\": 7}}",
                &["key `c_e_held`: the number 7, not true or false"],
            ),
            (
                "p.json",
                "{\"parameters\": {\"c_e\": 1.95, \"c_d\": 0, \"t_r\": 1.5, \"d\": 0}, \"verdict\": 5}",
                &["key `verdict`: the number 5; `verdict` is text"],
            ),
            (
                "p.json",
                "{\"parameters\": {\"c_e\": 1.95, \"c_d\": 0, \"t_r\": 1.5, \"d\": 0}, \"verdict_reasons\": \"x\"}",
                &["key `verdict_reasons`: not a list"],
            ),
            (
                "p.yaml",
                "odocal:\n  ros__parameters:\n    c_e: 1.95\n    c_d: 0.0\n    t_r: 1.5\n    d: 0.0\n    verdict: [1]\n",
                &["key `verdict[0]`"],
            ),
            (
                "p.yaml",
                "odocal:\n  ros__parameters:\n    c_e: 1.95\n    c_d: 0.0\n    t_r: 1.5\n    d: 0.0\n    t_r_held: yes\n",
                &["key `t_r_held`: the text 'yes', not true or false"],
            ),
            ("p.txt", "c_e: 1.95", &["use the .yaml, .yml or .json file"]),
        ] {
            let e = read_text(name, text).expect_err(text).to_string();
            assert!(e.contains(name), "{e}");
            for n in needles {
                assert!(e.contains(n), "expected '{n}' in: {e}");
            }
        }
    }

    #[test]
    fn extrinsics_entries_follow_theta() {
        use crate::model::extrinsics::{Extrinsics, ExtrinsicsEstimate};
        let mut f = sample();
        let x = ExtrinsicsEstimate {
            value: Extrinsics { lever_x: -0.9, lever_y: 0.0, heading_offset: -0.0099 },
            std_dev: Extrinsics { lever_x: 0.01, lever_y: 0.02, heading_offset: 1e-4 },
            free: crate::model::param::ParamSet::LEVER_ARM,
            ..ExtrinsicsEstimate::held(Extrinsics::ZERO)
        };
        f.add_extrinsics(&x);
        let j = f.to_json();
        let p = &j["parameters"];
        assert_eq!(p["lever_x"].as_f64(), Some(-0.9), "{j}");
        assert_eq!(p["lever_y_sigma"].as_f64(), Some(0.02), "{j}");
        assert_eq!(p["heading_offset"].as_f64(), Some(-0.0099), "{j}");
        assert_eq!(p["heading_offset_held"], serde_json::json!(true), "{j}");
        assert_eq!(j["units"]["heading_offset"], "rad", "{j}");
    }

    /// Each calibration drive's heading offset by its fingerprint: the
    /// file's own for one drive, each drive's own from the per-drive list
    /// (written and read back) for several, none where the calibration held
    /// the offset or the lists do not pair up.
    #[test]
    fn drive_heading_offsets_pair_fingerprints_with_offsets() {
        use crate::model::extrinsics::{DriveHeadingOffset, Extrinsics, ExtrinsicsEstimate};
        let estimate = |delta: f64| ExtrinsicsEstimate {
            value: Extrinsics { heading_offset: delta, ..Extrinsics::ZERO },
            std_dev: Extrinsics { heading_offset: 1e-4, ..Extrinsics::ZERO },
            free: ParamSet::EMPTY.with(Param::HeadingOffset),
            ..ExtrinsicsEstimate::held(Extrinsics::ZERO)
        };
        let fingerprint = |f: &mut ParamFile, v: &str| f.provenance.push(("fingerprint".into(), v.into()));
        let mut one = sample();
        one.add_extrinsics(&estimate(0.0188));
        assert!(one.drive_heading_offsets().is_empty(), "no fingerprint");
        fingerprint(&mut one, "aa");
        assert_eq!(one.drive_heading_offsets(), [("aa".to_string(), 0.0188)]);
        let mut held = sample();
        held.add_extrinsics(&ExtrinsicsEstimate::held(Extrinsics { heading_offset: 0.0188, ..Extrinsics::ZERO }));
        fingerprint(&mut held, "aa");
        assert!(held.drive_heading_offsets().is_empty(), "the calibration held δ");

        let deltas = [0.018799999999998464, -0.01419999999999986];
        let mut joint = estimate(0.5 * (deltas[0] + deltas[1]));
        joint.per_drive = deltas
            .iter()
            .enumerate()
            .map(|(drive, &value)| DriveHeadingOffset { drive, value, std_dev: 1e-4, robust_std_dev: None })
            .collect();
        let mut two = sample();
        two.add_extrinsics(&joint);
        fingerprint(&mut two, "aa, bb");
        let want = vec![("aa".to_string(), deltas[0]), ("bb".to_string(), deltas[1])];
        assert_eq!(two.drive_heading_offsets(), want);
        let back = read_text("p.yaml", &two.to_ros2_yaml()).expect("read back");
        assert_eq!(back.drive_heading_offsets(), want, "to the bit through the file");
        let mut three = two.clone();
        three.provenance.retain(|(k, _)| k != "fingerprint");
        fingerprint(&mut three, "aa, bb, cc");
        assert!(three.drive_heading_offsets().is_empty(), "three fingerprints, two offsets");
        for bad in [
            "drive 1: x ± 1 rad; drive 2: 1e-2 ± 1 rad",
            "drive 3: 1e-2 ± 1 rad; drive 1: 1e-2 ± 1 rad",
            "drive 1: 1e-2 ± 1 rad; drive 2: 4 ± 1 rad",
            "drive 1: 1e-2 ± 1 rad; drive 2: NaN ± 1 rad",
            "garbage",
        ] {
            let mut f = two.clone();
            for (k, v) in &mut f.provenance {
                if k == "heading_offset_per_drive" {
                    *v = bad.into();
                }
            }
            assert!(f.drive_heading_offsets().is_empty(), "{bad}");
        }
    }

    /// Every value under `ros__parameters` as ROS 2 types it: a list, a
    /// map or a missing value (`key:`) has no type when empty, and rclcpp
    /// refuses the whole file. The `(path, problem)` of each such value.
    fn untyped_ros2_values(text: &str) -> Vec<(String, &'static str)> {
        use yaml_rust2::Yaml;
        fn walk(path: &str, y: &Yaml, out: &mut Vec<(String, &'static str)>) {
            match y {
                Yaml::Array(a) if a.is_empty() => out.push((path.into(), "an empty list")),
                Yaml::Hash(h) if h.is_empty() => out.push((path.into(), "an empty map")),
                Yaml::Null => out.push((path.into(), "no value")),
                Yaml::Hash(h) => {
                    for (k, v) in h {
                        walk(&format!("{path}.{}", k.as_str().unwrap_or("?")), v, out);
                    }
                }
                _ => {}
            }
        }
        let docs = yaml_rust2::YamlLoader::load_from_str(text).expect("valid YAML");
        let mut out = Vec::new();
        walk("ros__parameters", &docs[0]["odocal"]["ros__parameters"], &mut out);
        out
    }

    /// An accepted result has no verdict reasons: the file leaves the key
    /// out (ROS 2 cannot type an empty list), in YAML and JSON alike, and
    /// reads back with none; a file holding `verdict_reasons: []` still reads.
    #[test]
    fn no_empty_list_lands_in_ros_parameters() {
        let mut f = with_extrinsics(sample());
        f.verdict_reasons.clear();
        let yaml = f.to_ros2_yaml();
        assert_eq!(untyped_ros2_values(&yaml), [], "{yaml}");
        assert!(!yaml.contains("verdict_reasons") && yaml.contains("verdict: \"accepted\""), "{yaml}");
        let j = f.to_json();
        assert!(j.get("verdict_reasons").is_none() && j["verdict"] == "accepted", "{j}");
        let dir = tempfile::tempdir().expect("tempdir");
        for name in ["p.yaml", "p.json"] {
            let path = dir.path().join(name);
            f.write(&path).expect("write");
            let back = ParamFile::read(&path, None).expect("read");
            assert_eq!((back.verdict.as_deref(), back.verdict_reasons.len()), (Some("accepted"), 0), "{name}");
        }
        // Nothing to say at all: no verdict, no provenance.
        let mut bare = ParamFile::from_theta(&Theta::PAPER_NOMINAL, [None; 4], "x", "eiv");
        bare.provenance.clear();
        assert_eq!(untyped_ros2_values(&bare.to_ros2_yaml()), [], "{}", bare.to_ros2_yaml());
        // With reasons, the list is written and reads back.
        let g = sample();
        assert_eq!(untyped_ros2_values(&g.to_ros2_yaml()), []);
        let path = dir.path().join("g.yaml");
        g.write(&path).expect("write");
        assert_eq!(ParamFile::read(&path, None).expect("read").verdict_reasons, g.verdict_reasons);
        // A file written with the empty list reads as no reasons.
        let old = yaml.replace("    verdict: \"accepted\"\n", "    verdict: \"accepted\"\n    verdict_reasons: []\n");
        let back = read_text("old.yaml", &old).expect("an empty list read");
        assert!(back.verdict_reasons.is_empty() && back.verdict.as_deref() == Some("accepted"));
    }

    #[test]
    fn json_and_extension() {
        let f = sample();
        let j = f.to_json();
        assert_eq!(j["parameters"]["t_r"].as_f64(), Some(1.564853));
        assert_eq!(j["parameters"]["d_held"].as_bool(), Some(true));
        let dir = tempfile::tempdir().expect("tmp");
        f.write(&dir.path().join("p.yaml")).expect("yaml");
        f.write(&dir.path().join("p.json")).expect("json");
        let e = f.write(&dir.path().join("p.txt")).expect_err("txt");
        assert!(matches!(e, Error::ParamFile { .. }), "{e:?}");
        let e = e.to_string();
        assert!(e.contains(".yaml, .yml or .json") && e.contains("p.txt") && !e.contains("params_out"), "{e}");
    }

    /// A file `read` would refuse is not written: a θ or σ that is not
    /// finite, a negative σ, a θ outside the physical limits.
    #[test]
    fn values_read_would_refuse_are_not_written() {
        let dir = tempfile::tempdir().expect("tmp");
        let th = Theta::PAPER_NOMINAL;
        let ok = [Some(1e-4); 4];
        for (theta, sigma, key) in [
            (Theta { c_e: f64::NAN, ..th }, ok, "key `c_e`: NaN is not a finite number"),
            (th, [Some(-1.0), None, None, None], "key `c_e_sigma`: -1 is negative"),
            (th, [None, Some(f64::INFINITY), None, None], "key `c_d_sigma`: inf is not a finite number"),
            (Theta { c_e: 1e6, ..th }, ok, "c_e = 1000000 m is outside"),
        ] {
            let f = ParamFile::from_theta(&theta, sigma, "x", "eiv");
            for name in ["p.yaml", "p.json"] {
                let p = dir.path().join(name);
                let e = f.write(&p).expect_err(key).to_string();
                assert!(e.contains(key) && e.contains(name), "{e}");
                assert!(!p.exists());
            }
        }
    }
}
