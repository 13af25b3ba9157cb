//! Reading and writing drives and parameters: the manifest importer
//! (`import`: manifests, CSV and Parquet sources, ROS 2 bags, clock
//! offset), the bag reader ([`bag`], feature `mcap`) and parameter files
//! (`param_file`). Calibration settings a manifest states are carried
//! as plain data; [`crate::calibrate::settings`] interprets them.

#[cfg(feature = "mcap")]
pub mod bag;
pub(crate) mod import;
pub(crate) mod param_file;
