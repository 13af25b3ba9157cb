//! Judging a θ and a calibration: the dead-reckoning error Ē_p
//! ([`position_error`], SPEC §7), the σ for the next drive ([`pooling`]), validation on the drive and on other
//! drives ([`validate`], [`validation_drives`]), the reachable minimum of
//! Ē_p ([`reachable`]), the trust checks and verdict ([`trust`]) and the
//! warnings a calibration reports ([`warning`]).

pub(crate) mod heading_offset;
pub mod pooling;
pub(crate) mod position_error;
pub(crate) mod reachable;
pub(crate) mod trust;
pub(crate) mod validate;
pub(crate) mod validation_drives;
pub(crate) mod warning;
