//! Reading drives and parameters. Public here: the ROS 2 bag reader
//! ([`bag`], feature `mcap`). Expert API, for programs that read bag topics
//! as tables or draft manifests (`odocal inspect`); importing a drive is
//! [`crate::load_drive`] / [`crate::import`], parameter files
//! [`crate::ParamFile`], at the root. Calibration settings a manifest
//! states are carried as plain data; [`crate::settings`] interprets them.

#[cfg(feature = "mcap")]
pub mod bag;
pub(crate) mod import;
pub(crate) mod param_file;
