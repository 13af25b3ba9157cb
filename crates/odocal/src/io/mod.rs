//! Reading drives and parameters. Public here, expert API: the ROS 2 bag
//! reader (module `bag`, with the default feature `mcap`), for programs that read bag topics as
//! tables or draft manifests (`odocal inspect`); a manifest's raw messages
//! imported as they arrive ([`RawStream`]); and a drive file read in chunks
//! as if live ([`Replay`]), for an online calibrator. Importing a drive is
//! [`crate::load_drive`] / [`crate::import`], parameter files
//! [`crate::ParamFile`], at the root. Calibration settings a manifest
//! states are carried as plain data; [`crate::settings`] interprets them.

#[cfg(feature = "mcap")]
pub mod bag;
pub(crate) mod exact;
pub(crate) mod import;
pub(crate) mod param_file;
mod replay;
pub(crate) mod toml_text;

pub use import::stream::RawStream;
pub use replay::Replay;
