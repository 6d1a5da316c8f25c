//! The dam break in three dimensions, a scale demonstration: the column `[0, a] × [0, b] ×
//! [0, 2a]` (width `a` along `x`, depth `b` along `y`, height `2a` along `z`, up) at rest
//! against the wall `x = 0` of the open tank `[0, L a] × [0, b] × [0, 2a]` (walls on the five
//! sides but the top), released under gravity `g` along `−z`. Built, observed and reported by
//! the same generic code as the 2D [`super::dam_break`] ([`ColumnScene`]).
//!
//! The column fills the tank's whole depth, so the flow is the 2D one extruded along `y` (with
//! no-slip side walls, slowed by them within a boundary layer): Martin & Moyce's experiment
//! (their column also spanned the tank's width) still applies, and the front `Z` and column
//! height `H` are compared with it as in 2D (the front is the largest `x` of the water over the
//! whole depth, the height the largest `z` within `Δx` of the wall `x = 0`).
//!
//! The walls are free-slip by default, as in 2D: with no-slip walls the runs reach
//! T = 3 (2026-11-28, n = 8 … 26), but the band particles at the wall `x = 0` hang there as a
//! film (column height 22–25 % off the experiment, 2 % free-slip) and the particles of the
//! front's bottom corners are thrown back into the water, held only by the wall margin
//! (README, the 3D dam break).
//!
//! Units as in 2D: `a = 1`, `g` = the `gravity` key, `re = √(g a³)/ν`, `n` particles across
//! the column's width (`Δx = a/n`); the depth is rounded to whole spacings (`round(b n)`
//! particles). The column holds `n · 2n · round(b n)` particles: `n = 26`, `b = 74/26` gives
//! 100 048.

use super::dam_break::{ColumnScene, ColumnSpec, DamBreak, DamBreakResult};
use super::hydrostatic::WallKind;
use super::{run_scene, FlowConfig, SceneConfig, SceneParams};
use crate::error::{Error, InputError};
use crate::flow::FreeSurface;
use serde::{Deserialize, Serialize};
use std::ops::ControlFlow;

/// The 3D dam break's own configuration keys (beside the shared [`FlowConfig`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DamBreak3d {
    /// Tank length over the column width `L` (default 5: the front travels 4a).
    pub length: f64,
    /// Depth of column and tank over the column width `b/a` (default 1), rounded to whole
    /// particle spacings.
    pub depth: f64,
    /// Gravity `g` (default 1), acting along `−z`.
    pub gravity: f64,
    /// Free-surface detection.
    pub free_surface: FreeSurface,
    /// The walls: `free_slip` (default, as in 2D) or `no_slip` (module docs; README, "The 3D
    /// dam break").
    pub walls: WallKind,
}

super::config_fields!(DamBreak3d {
    length,
    depth,
    gravity,
    free_surface,
    walls
});

impl Default for DamBreak3d {
    fn default() -> Self {
        let d = DamBreak::default();
        DamBreak3d {
            length: d.length,
            depth: 1.0,
            gravity: d.gravity,
            free_surface: d.free_surface,
            walls: WallKind::FreeSlip,
        }
    }
}

/// Configuration of a 3D dam-break run (one flat object; unknown keys are rejected).
pub type DamBreak3dConfig = SceneConfig<DamBreak3d>;

impl SceneParams for DamBreak3d {
    const NAME: &'static str = "dam_break_3d";
    const MIN_N: usize = 6;

    /// The 2D dam break's (non-incremental scheme, `h = 4Δx`, free-surface defaults) with
    /// `n = 16` (8 192 particles at `b = 1`).
    fn default_flow() -> FlowConfig {
        FlowConfig {
            n: 16,
            ..DamBreak::default_flow()
        }
    }

    fn validate(&self, flow: &FlowConfig) -> Result<(), InputError> {
        if !(self.depth.is_finite() && (0.1..=20.0).contains(&self.depth)) {
            return Err(InputError::parameter(
                "depth",
                self.depth,
                "the depth over the column width must be in [0.1, 20]",
            ));
        }
        self.as_2d().validate(flow)
    }
}

impl DamBreak3d {
    /// The keys the 2D dam break shares.
    fn as_2d(&self) -> DamBreak {
        DamBreak {
            length: self.length,
            gravity: self.gravity,
            free_surface: self.free_surface,
            walls: self.walls,
        }
    }
}

impl ColumnScene<3> for DamBreak3d {
    const TITLE: &'static str = "3D dam break";
    fn spec(&self) -> ColumnSpec {
        ColumnSpec {
            depth: self.depth,
            ..ColumnScene::<2>::spec(&self.as_2d())
        }
    }
}

/// Runs a 3D dam break to `t_end` through [`run_scene`].
pub fn run(cfg: &DamBreak3dConfig) -> Result<DamBreakResult, Error> {
    Ok(run_scene(cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(())))?.result)
}
