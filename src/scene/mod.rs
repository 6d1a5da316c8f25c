//! Ready-made scenes.

pub mod cavity;
pub mod taylor_green;
