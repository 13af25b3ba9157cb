//! Judging a θ and a calibration: the dead-reckoning error Ē_p
//! ([`position_error`], SPEC §7), validation on the drive and on other
//! drives ([`validate`], [`validation_drives`]), the reachable minimum of
//! Ē_p ([`reachable`]), the trust checks and verdict ([`trust`]) and the
//! warnings a calibration reports ([`warning`]).

pub mod position_error;
pub mod reachable;
pub mod trust;
pub mod validate;
pub mod validation_drives;
pub mod warning;
