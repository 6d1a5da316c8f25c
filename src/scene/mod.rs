//! Ready-made scenes, and the one generic path every scene runs through.
//!
//! A scene is a type implementing [`SceneParams`] (its own configuration keys, serde-readable)
//! and [`Scene`] (how it builds a [`Simulation`], what it observes every step, what it reports
//! at the end). Its full configuration is a [`SceneConfig`]: the keys every flow shares
//! ([`FlowConfig`]: `re`, `n`, `t_end`, `limits`, `solve`, …) and the scene's own keys
//! (`lid`, `steady`, `amplitude`, …), read and written as one flat JSON object.
//!
//! [`run_scene`] runs any scene: build, step until `t_end` or until the scene or the caller's
//! observer returns [`ControlFlow::Break`], then summarise. [`run_recorded`] adds an MCAP
//! recording (finished whatever happened). `gpm run <scene>` and the examples dispatch by name
//! through [`visit_scene`]; **adding a scene** is one new file implementing the two traits plus
//! one line in the `registry!` invocation at the end of this module.
//!
//! Library code writes no files on its own: [`SceneRun::write_tables`] and the plot writers
//! (feature `cli`) write only where the caller asks.

pub mod cavity;
pub mod channel;
pub mod corner;
pub mod cube;
pub mod dam_break;
pub mod dam_break_3d;
pub mod hydrostatic;
pub mod manufactured;
pub mod ranks;
pub mod taylor_green;
pub mod warm_start;

use crate::boundary::Boundary;
use crate::consistent::{GradientKind, LaplacianKind};
use crate::error::{Error, InputError};
use crate::flow::{
    ConvectionForm, FlowParams, FlowReport, Integrator, Motion, Shifting, Simulation,
    TimeStepLimits, VolumeRule,
};
use crate::kernel::Weight;
use crate::neighbors::NeighborConfig;
use crate::poisson::SolveParams;
use crate::projection::{Disconnected, ProjectionParams, Scheme};
use crate::record::schema::ToBoundarySpec;
use crate::record::{
    OutputLock, RecordError, RecordLevel, RecordSummary, Recorder, RecorderOptions,
};
use serde::de::{DeserializeOwned, DeserializeSeed, MapAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize};
use std::fmt;
use std::marker::PhantomData;
use std::ops::{ControlFlow, Deref, DerefMut};
use std::path::Path;
use std::time::Instant;

// ---------------------------------------------------------------------------------------------
// configuration

/// Largest `n` (particles per side) a configuration accepts; the memory of a run is checked
/// separately ([`FlowConfig::memory_estimate`], `gpm run` refuses a run that does not fit).
pub const MAX_N: usize = 10_000;

/// The configuration keys every flow scene shares (flattened into each [`SceneConfig`]).
///
/// The physical viscosity is `ν = U / Re` with the scene's velocity scale `U` (lid speed,
/// vortex amplitude, …); the particle spacing is `Δx = 1/n` on the unit square.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlowConfig {
    /// Reynolds number `U L / ν`, positive and finite.
    pub re: f64,
    /// Fluid particles per side, from the scene's `MIN_N` to [`MAX_N`].
    pub n: usize,
    /// End time (a scene may stop earlier, e.g. the cavity once steady), positive and finite;
    /// a run must take at least one step.
    pub t_end: f64,
    /// Influence radius over particle spacing, `h/Δx` in (1, 8].
    pub h_over_dx: f64,
    /// Neighbour skin over `h`, in [0, 2].
    pub skin_over_h: f64,
    /// Reference weight.
    pub weight: Weight,
    /// Pressure-correction scheme.
    pub scheme: Scheme,
    /// Gradient of the predictor and the correction (difference `∇h` or renormalised `B∇h`).
    /// The consistent operator set replaces the default `difference` by the least-squares
    /// gradient; `renormalised` stays the user's choice there too.
    pub gradient: GradientKind,
    /// Divergence of the Poisson source (`"sum_form"`, `"adjoint_bt"`, `"renormalised"` or
    /// `"least_squares"`, [`crate::projection::SourceKind`]); `null` (default) takes the operator
    /// set's (the sum form for `gpm`, least squares for `consistent`).
    pub source: Option<crate::projection::SourceKind>,
    /// Frame of the particles.
    pub motion: Motion,
    /// Integrator of the explicit terms.
    pub integrator: Integrator,
    /// Discretisation of the convective term (Eulerian frame): `"skew_symmetric"` (default),
    /// `"central"`, `"upwind"`, `"muscl"` or `"muscl_van_leer"` ([`ConvectionForm`],
    /// formulas in [`crate::flow::convection`]).
    pub convection: ConvectionForm,
    /// Implicit weight of the viscous term (½ = Crank–Nicolson, 0 = explicit), in [0, 1].
    pub viscous_theta: f64,
    /// Laplacian of the viscous term (`"gpm"` or `"least_squares"`, [`LaplacianKind`]); `null`
    /// takes the operator set's (`gpm` for the GPM set, `least_squares` for the consistent
    /// one). The least-squares one is exact on quadratic velocities that take the wall value,
    /// where the GPM `Δh` with no-slip images is not within `h` of a wall; the cavity and the
    /// cube default to it ([`cavity::WALL_LAPLACIAN`], measured there), the other scenes to
    /// `null`.
    pub laplacian: Option<LaplacianKind>,
    /// Particle shifting (Lagrangian runs only).
    pub shifting: Option<Shifting>,
    /// Volumes.
    pub volumes: VolumeRule,
    /// Pair weights (`"plain"` or `"moment"`).
    pub pair_weights: crate::pair_weights::PairWeights,
    /// Operator set (`"auto"`, `"gpm"` or `"consistent"`, see [`OperatorSet`]).
    pub operators: OperatorSet,
    /// Time-step limits: `cfl`, `visc`, `force` in (0, 1], `u_ref` in [0, 10⁶], `dt_max` and
    /// `dt_fixed` positive and finite when set (see [`FlowConfig::validate`]).
    pub limits: TimeStepLimits,
    /// Linear solver.
    pub solve: SolveParams,
    /// Policy for fluid cut off from the rest ([`Disconnected`]): `null` (default) is `float`
    /// for Lagrangian runs, where particles can leave the bulk, and `fail` for fixed ones.
    pub disconnected: Option<Disconnected>,
    /// A warm start: the path of another run's final fluid particles (the CSV of
    /// [`crate::particles::Particles::fluid_csv`], the examples' `--particles-csv`), whose
    /// velocity and pressure are sampled at this run's fluid particles before the first step
    /// ([`warm_start`]; e.g. a coarse run's steady state as the start of a fine one). `null`
    /// (default): the scene's own initial state.
    pub initial: Option<std::path::PathBuf>,
}

impl Default for FlowConfig {
    /// Re 100, n = 50, t_end = 1, h = 3Δx, Wendland C2, rotational scheme, Eulerian, AB2,
    /// Crank–Nicolson viscosity, number-density volumes.
    fn default() -> Self {
        FlowConfig {
            re: 100.0,
            n: 50,
            t_end: 1.0,
            h_over_dx: 3.0,
            skin_over_h: 0.3,
            weight: Weight::WendlandC2,
            scheme: Scheme::Rotational,
            gradient: GradientKind::Difference,
            source: None,
            motion: Motion::Eulerian,
            integrator: Integrator::Ab2,
            convection: ConvectionForm::SkewSymmetric,
            viscous_theta: 0.5,
            laplacian: None,
            shifting: Some(Shifting::default()),
            volumes: VolumeRule::NumberDensity,
            pair_weights: Default::default(),
            operators: OperatorSet::Auto,
            limits: TimeStepLimits::default(),
            solve: SolveParams::default(),
            disconnected: None,
            initial: None,
        }
    }
}

impl FlowConfig {
    /// Checks every shared parameter and names the first bad one; `min_n` is the scene's
    /// smallest resolution.
    pub fn validate(&self, min_n: usize) -> Result<(), InputError> {
        let bad = |name: &'static str, value: f64, reason: &str| {
            Err(InputError::Parameter {
                name: name.into(),
                value,
                reason: reason.into(),
            })
        };
        if !(self.re > 0.0 && self.re.is_finite()) {
            return bad(
                "re",
                self.re,
                "the Reynolds number must be positive and finite",
            );
        }
        if self.n < min_n || self.n > MAX_N {
            return bad(
                "n",
                self.n as f64,
                &format!("particles per side must be in {min_n}..={MAX_N}"),
            );
        }
        if !(self.t_end > 0.0 && self.t_end.is_finite()) {
            return bad(
                "t_end",
                self.t_end,
                "the end time must be positive and finite",
            );
        }
        if !(self.h_over_dx > 1.0 && self.h_over_dx <= 8.0) {
            return bad(
                "h_over_dx",
                self.h_over_dx,
                "h must exceed the particle spacing (h/dx > 1) and h/dx ≤ 8",
            );
        }
        if !(self.skin_over_h >= 0.0 && self.skin_over_h <= 2.0) {
            return bad(
                "skin_over_h",
                self.skin_over_h,
                "the skin must be in [0, 2] h",
            );
        }
        if let Err(reason) = self.weight.validate() {
            return bad("weight", f64::NAN, &reason);
        }
        if !(0.0..=1.0).contains(&self.viscous_theta) {
            return bad("viscous_theta", self.viscous_theta, "must be in [0, 1]");
        }
        self.limits.validate()?;
        for (name, v) in [
            ("limits.cfl", self.limits.cfl),
            ("limits.visc", self.limits.visc),
            ("limits.force", self.limits.force),
        ] {
            if v > 1.0 {
                return bad(
                    name,
                    v,
                    "time-step factors must be in (0, 1] (a particle may not cross more than h, \
                     nor the explicit viscous or body-force limit be exceeded, in one step)",
                );
            }
        }
        if self.limits.u_ref > 1e6 {
            return bad("limits.u_ref", self.limits.u_ref, "must be in [0, 1e6]");
        }
        self.solve.validate()?;
        match &self.shifting {
            Some(s) => s.validate(),
            None => Ok(()),
        }
    }

    /// An upper estimate of the particles (ghosts included) and of the peak memory of a run in
    /// `D` dimensions, before anything is allocated: `(n + 2 r)^D` particles with
    /// `r = (h/Δx)(1 + skin/h)` ghost layers, and `1 kB + 60 B` per neighbour candidate
    /// (`π r²` in 2D, `4/3 π r³` in 3D) for each. Measured peaks (README, Performance: 2D,
    /// `h = 3Δx`: 293 MB at 10⁵ and 2.7 GB at 10⁶ particles) are 1.3–1.5× below it.
    pub fn memory_estimate<const D: usize>(&self) -> (f64, f64) {
        let r = self.h_over_dx * (1.0 + self.skin_over_h);
        let side = self.n as f64 + 2.0 * r.ceil();
        let particles = side.powi(D as i32);
        let candidates = if D == 3 {
            4.0 / 3.0 * std::f64::consts::PI * r.powi(3)
        } else {
            std::f64::consts::PI * r * r
        };
        (particles, particles * (1000.0 + 60.0 * candidates))
    }

    /// Particle spacing `Δx = 1/n`.
    pub fn dx(&self) -> f64 {
        1.0 / self.n as f64
    }

    /// The neighbour configuration: `h = (h/Δx) Δx`, skin `(skin/h) h`.
    pub fn neighbor_config<const D: usize>(&self) -> NeighborConfig<D> {
        NeighborConfig::new_relative(self.weight, self.dx(), self.h_over_dx, self.skin_over_h)
    }

    /// The flow parameters for velocity scale `u_ref` (`ν = |u_ref| / Re`; the time-step
    /// limits' `u_ref` is raised to `|u_ref|`; shifting only for Lagrangian runs; one floating
    /// pressure mode allowed). The scene sets what is its own (e.g. the source ghosts).
    pub fn flow_params<const D: usize>(&self, u_ref: f64) -> FlowParams<D> {
        let mut projection = ProjectionParams::new(u_ref.abs() / self.re);
        projection.scheme = self.scheme;
        projection.gradient = self.gradient;
        if self.operators.consistent(self.motion == Motion::Lagrangian) {
            projection = projection.with_consistent_operators();
            // a gradient other than the default is the user's choice over the set's
            if self.gradient != GradientKind::Difference {
                projection.gradient = self.gradient;
            }
        }
        if let Some(s) = self.source {
            projection.source = s;
        }
        projection.viscous_theta = self.viscous_theta;
        if let Some(l) = self.laplacian {
            projection.laplacian = l;
        }
        projection.solve = self.solve;
        projection.allowed_floating = 1;
        projection.disconnected = self.disconnected.unwrap_or(match self.motion {
            Motion::Lagrangian => Disconnected::Float,
            Motion::Eulerian => Disconnected::Fail,
        });
        let mut limits = self.limits;
        limits.u_ref = limits.u_ref.max(u_ref.abs());
        FlowParams {
            projection,
            limits,
            motion: self.motion,
            integrator: self.integrator,
            convection: self.convection,
            shifting: if self.motion == Motion::Lagrangian {
                self.shifting
            } else {
                None
            },
            volumes: self.volumes,
            pair_weights: self.pair_weights,
            dx: self.dx(),
        }
    }
}

/// Which operators a flow uses besides the Poisson matrix (always the GPM `Δh`: SPD under
/// h-connectivity, so the theory's checks apply to every set).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OperatorSet {
    /// `consistent` for moving particles (and for scenes whose fixed particles are
    /// disordered, e.g. a jittered channel), `gpm` on a lattice.
    #[default]
    Auto,
    /// The GPM forms: sum-form divergence `∇̂h·`, the `gradient` key's gradient, `Δh` for the
    /// viscous term (Lemma 4.3's adjoint pair; consistent only on symmetric neighbourhoods).
    Gpm,
    /// The consistent forms of [`ProjectionParams::with_consistent_operators`]: `∇ᶜ·` for the
    /// source and the rotational term, `∇ᶜ` for the pressure gradients, `Δˡˢ` for viscosity
    /// (exact on linear / quadratic fields on any distribution; `∇ᶜ·` and `∇ᶜ` not adjoint).
    Consistent,
}

impl OperatorSet {
    /// Whether the set is the consistent one, `disordered` deciding [`OperatorSet::Auto`].
    pub fn consistent(self, disordered: bool) -> bool {
        match self {
            OperatorSet::Auto => disordered,
            OperatorSet::Gpm => false,
            OperatorSet::Consistent => true,
        }
    }
}

impl std::str::FromStr for OperatorSet {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(OperatorSet::Auto),
            "gpm" => Ok(OperatorSet::Gpm),
            "consistent" => Ok(OperatorSet::Consistent),
            _ => Err(format!(
                "unknown operator set '{s}': expected auto, gpm or consistent"
            )),
        }
    }
}

/// A configuration struct read key by key, so that its keys can be merged with others into one
/// flat JSON object while unknown keys are still rejected (serde's `flatten` cannot do both).
pub trait ConfigFields: Sized {
    /// The keys, in serialisation order.
    const FIELDS: &'static [&'static str];
    /// Reads the value of `key` from `map` into its field; `Ok(false)` when `key` is not one of
    /// [`FIELDS`](Self::FIELDS).
    fn read_field<'de, A: MapAccess<'de>>(
        &mut self,
        key: &str,
        map: &mut A,
    ) -> Result<bool, A::Error>;
}

/// Implements [`ConfigFields`] for a struct from the list of its fields.
macro_rules! config_fields {
    ($ty:ty { $($field:ident),* $(,)? }) => {
        impl $crate::scene::ConfigFields for $ty {
            const FIELDS: &'static [&'static str] = &[$(stringify!($field)),*];
            fn read_field<'de, A: serde::de::MapAccess<'de>>(
                &mut self,
                key: &str,
                map: &mut A,
            ) -> Result<bool, A::Error> {
                match key {
                    $(stringify!($field) => self.$field = map.next_value()?,)*
                    _ => return Ok(false),
                }
                Ok(true)
            }
        }
    };
}
pub(crate) use config_fields;

config_fields!(FlowConfig {
    re,
    n,
    t_end,
    h_over_dx,
    skin_over_h,
    weight,
    scheme,
    gradient,
    source,
    motion,
    integrator,
    convection,
    viscous_theta,
    laplacian,
    shifting,
    volumes,
    pair_weights,
    operators,
    limits,
    solve,
    disconnected,
    initial
});

/// A scene's own configuration keys (beside the shared [`FlowConfig`]); independent of the
/// dimension.
pub trait SceneParams: ConfigFields + Clone + fmt::Debug + PartialEq + Default + Serialize {
    /// The scene's name in `gpm run <name>` and in a recording's `/config` (`snake_case`;
    /// the command line also accepts `-` for `_`).
    const NAME: &'static str;
    /// Smallest number of particles per side.
    const MIN_N: usize = 4;
    /// The shared keys' defaults for this scene (e.g. its end time).
    fn default_flow() -> FlowConfig;
    /// Checks the scene's own keys, naming the first bad one (the shared keys are already
    /// checked).
    fn validate(&self, flow: &FlowConfig) -> Result<(), InputError>;
    /// The CFL factor (`limits.cfl`) the scene needs with the shared keys `flow` (its frame,
    /// Reynolds number, resolution) when neither the command line nor the configuration gives
    /// one; `None` (the default): `limits.cfl` of [`default_flow`](Self::default_flow). See
    /// [`SceneConfig::default_cfl`].
    fn frame_cfl(_flow: &FlowConfig) -> Option<f64> {
        None
    }
}

/// A scene's full configuration: the shared keys and the scene's own, one flat JSON object
/// (unknown keys rejected, missing keys take the scene's defaults). Dereferences to the shared
/// [`FlowConfig`], so `cfg.n` and `cfg.limits.cfl` read and write the shared keys.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SceneConfig<S> {
    /// The keys every flow shares.
    #[serde(flatten)]
    pub flow: FlowConfig,
    /// The scene's own keys.
    #[serde(flatten)]
    pub scene: S,
}

impl<S: SceneParams> Default for SceneConfig<S> {
    fn default() -> Self {
        SceneConfig {
            flow: S::default_flow(),
            scene: S::default(),
        }
    }
}

impl<S> Deref for SceneConfig<S> {
    type Target = FlowConfig;
    fn deref(&self) -> &FlowConfig {
        &self.flow
    }
}

impl<S> DerefMut for SceneConfig<S> {
    fn deref_mut(&mut self) -> &mut FlowConfig {
        &mut self.flow
    }
}

impl<S: SceneParams> SceneConfig<S> {
    /// Checks every parameter (shared keys first, then the scene's) and names the first bad
    /// one.
    pub fn validate(&self) -> Result<(), InputError> {
        self.flow.validate(S::MIN_N)?;
        self.scene.validate(&self.flow)
    }

    /// The CFL factor this configuration runs with unless one is given: the scene's
    /// [`SceneParams::frame_cfl`] for its frame, Reynolds number and resolution (the Lagrangian
    /// cavity needs less than the default 0.2), else the scene's default `limits.cfl`.
    /// [`scene_config_from_json`] sets it when the file has no `limits.cfl`; `gpm run` sets it
    /// after its flags when neither `--cfl` nor the file gives one.
    pub fn default_cfl(&self) -> f64 {
        S::frame_cfl(&self.flow).unwrap_or(S::default_flow().limits.cfl)
    }

    /// The `/config` message of a recording: `{"scene": NAME, "config": {…}}`, which
    /// `gpm run <scene> --config FILE` reads back.
    pub fn record_header(&self) -> serde_json::Value {
        serde_json::json!({ "scene": S::NAME, "config": self })
    }

    /// The configuration changed by `f`: `CavityConfig::default().with(|c| c.n = 24)`.
    pub fn with(mut self, f: impl FnOnce(&mut Self)) -> Self {
        f(&mut self);
        self
    }

    /// Every key, shared and the scene's own.
    pub fn keys() -> impl Iterator<Item = &'static str> {
        FlowConfig::FIELDS.iter().chain(S::FIELDS).copied()
    }
}

impl<'de, S: SceneParams> Deserialize<'de> for SceneConfig<S> {
    fn deserialize<De: Deserializer<'de>>(d: De) -> Result<Self, De::Error> {
        d.deserialize_map(ConfigVisitor(PhantomData))
    }
}

struct ConfigVisitor<S>(PhantomData<S>);

impl<'de, S: SceneParams> Visitor<'de> for ConfigVisitor<S> {
    type Value = SceneConfig<S>;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(
            f,
            "a {} configuration (a JSON object of named keys)",
            S::NAME
        )
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        let mut cfg = SceneConfig::<S>::default();
        let mut seen: Vec<&'static str> = Vec::new();
        while let Some(key) = map.next_key_seed(KeySeed::<S> {
            seen: &seen,
            scene: PhantomData,
        })? {
            seen.push(key);
            if !cfg.flow.read_field(key, &mut map)? {
                cfg.scene.read_field(key, &mut map)?;
            }
        }
        Ok(cfg)
    }
}

/// Reads a key and checks it against the known ones *while* reading it, so that an error
/// names the key (`serde_path_to_error` records the key's path when its own deserialisation
/// fails).
struct KeySeed<'a, S> {
    seen: &'a [&'static str],
    scene: PhantomData<S>,
}

impl<'de, S: SceneParams> DeserializeSeed<'de> for KeySeed<'_, S> {
    type Value = &'static str;
    fn deserialize<De: Deserializer<'de>>(self, d: De) -> Result<&'static str, De::Error> {
        d.deserialize_identifier(self)
    }
}

impl<'de, S: SceneParams> Visitor<'de> for KeySeed<'_, S> {
    type Value = &'static str;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a configuration key")
    }
    fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<&'static str, E> {
        match SceneConfig::<S>::keys().find(|k| *k == v) {
            Some(k) if self.seen.contains(&k) => Err(E::duplicate_field(k)),
            Some(k) => Ok(k),
            None => {
                let expected: Vec<String> =
                    SceneConfig::<S>::keys().map(|k| format!("`{k}`")).collect();
                Err(E::custom(format_args!(
                    "unknown field `{v}`, expected one of {}",
                    expected.join(", ")
                )))
            }
        }
    }
}

/// Reads a scene configuration ([`cavity::CavityConfig`], [`taylor_green::TaylorGreenConfig`])
/// from JSON text, strictly: the document must be one JSON object; duplicate keys (at any depth),
/// unknown keys, ill-typed values and arrays given for a structure (serde would read them by
/// position) are rejected with an [`InputError::Config`] naming the key (`limits.cfl`, `n`;
/// `(top level)` for the document itself). The values are checked by the configuration's own
/// `validate`, which the scene's `build` calls.
///
/// ```
/// use gpm::error::InputError;
/// use gpm::scene::{cavity::CavityConfig, config_from_json};
///
/// let cfg: CavityConfig = config_from_json(r#"{"re": 400, "n": 32}"#)?;
/// assert_eq!((cfg.re, cfg.n), (400.0, 32));
/// for (text, bad_key) in [
///     (r#"{"limits": {"cfl": "fast"}}"#, "limits.cfl"),
///     (r#"{"limits": {"cfl": 0.1, "cfl": 0.2}}"#, "limits.cfl"),
///     (r#"{"limits": [0.1, 0.5]}"#, "limits"),
/// ] {
///     match config_from_json::<CavityConfig>(text) {
///         Err(InputError::Config { key, .. }) => assert_eq!(key, bad_key),
///         other => panic!("{other:?}"),
///     }
/// }
/// # Ok::<(), InputError>(())
/// ```
pub fn config_from_json<T: DeserializeOwned + Serialize + Default>(
    text: &str,
) -> Result<T, InputError> {
    config_from_value(strict_json(text)?)
}

/// [`config_from_json`] for an already parsed JSON value (e.g. the `config` member of a
/// recorded `/config` message). Duplicate keys cannot be seen in a [`serde_json::Value`]
/// (the last one won when it was parsed): parse text with [`strict_json`] first.
pub fn config_from_value<T: DeserializeOwned + Serialize + Default>(
    value: serde_json::Value,
) -> Result<T, InputError> {
    if !value.is_object() {
        return Err(not_an_object());
    }
    let reference = serde_json::to_value(T::default()).map_err(|e| InputError::Config {
        key: "(top level)".into(),
        reason: e.to_string(),
    })?;
    no_positional(&value, &reference, "")?;
    serde_path_to_error::deserialize(value).map_err(config_error)
}

/// Reads a scene's configuration file: a bare configuration, or a recording's `/config`
/// message `{"scene": NAME, "config": {…}}` (then `scene` must be `S`'s name), strictly as
/// [`config_from_json`]. This is what `gpm run <scene> --config FILE` reads. A file without
/// `limits.cfl` gets the configuration's [`SceneConfig::default_cfl`] (e.g. the Lagrangian
/// cavity's smaller step).
pub fn scene_config_from_json<S: SceneParams>(text: &str) -> Result<SceneConfig<S>, InputError> {
    let (v, wrapped) = scene_config_value::<S>(text)?;
    let sets_cfl = value_sets_cfl(&v);
    let mut cfg: SceneConfig<S> = config_from_value(v).map_err(|e| match e {
        InputError::Config { key, reason } if wrapped && key != "(top level)" => {
            InputError::Config {
                key: format!("config.{key}"),
                reason,
            }
        }
        e => e,
    })?;
    if !sets_cfl {
        cfg.flow.limits.cfl = cfg.default_cfl();
    }
    Ok(cfg)
}

/// Whether a scene's configuration file (as [`scene_config_from_json`] reads it) gives
/// `limits.cfl` itself; `false` for a file that does not parse.
pub fn scene_config_sets_cfl<S: SceneParams>(text: &str) -> bool {
    scene_config_value::<S>(text).is_ok_and(|(v, _)| value_sets_cfl(&v))
}

fn value_sets_cfl(v: &serde_json::Value) -> bool {
    v.get("limits").and_then(|l| l.get("cfl")).is_some()
}

/// The configuration object of a file [`scene_config_from_json`] reads, and whether it was
/// wrapped in a recording's `/config` message (whose `scene` is checked).
fn scene_config_value<S: SceneParams>(text: &str) -> Result<(serde_json::Value, bool), InputError> {
    let mut v = strict_json(text)?;
    if let serde_json::Value::Object(m) = &mut v {
        let Some(inner) = m.remove("config") else {
            return Ok((v, false));
        };
        if let Some(scene) = m.remove("scene") {
            match scene.as_str() {
                Some(s) if s.trim().to_ascii_lowercase().replace('-', "_") == S::NAME => {}
                other => {
                    let named = other.map_or_else(|| scene.to_string(), |s| s.to_string());
                    return Err(InputError::Config {
                        key: "scene".into(),
                        reason: format!(
                            "the file configures the scene '{named}', not '{}'",
                            S::NAME
                        ),
                    });
                }
            }
        }
        return Ok((inner, true));
    }
    Ok((v, false))
}

/// JSON text to a [`serde_json::Value`], rejecting what `serde_json::from_str` lets pass: a
/// key given twice in one object (the last would silently win), named by its path
/// (`limits.cfl`), and trailing characters. Syntax errors are [`InputError::Config`] on
/// `(top level)` with serde's line and column. Nesting is limited by serde_json (128 levels).
pub fn strict_json(text: &str) -> Result<serde_json::Value, InputError> {
    let mut de = serde_json::Deserializer::from_str(text);
    let at = std::cell::RefCell::new(None);
    let v = StrictValue {
        path: String::new(),
        at: &at,
    }
    .deserialize(&mut de)
    .and_then(|v| de.end().map(|_| v));
    v.map_err(|e| InputError::Config {
        key: at.into_inner().unwrap_or_else(|| "(top level)".into()),
        reason: if e.is_syntax() || e.is_eof() {
            format!("the text is not JSON: {e}")
        } else {
            e.to_string()
        },
    })
}

/// A [`serde_json::Value`] built key by key with the path of each, so that an error names the
/// innermost key it happened under (`at` receives its path: a duplicate key, a bad value).
struct StrictValue<'a> {
    path: String,
    at: &'a std::cell::RefCell<Option<String>>,
}

impl StrictValue<'_> {
    fn child(&self, key: &str) -> String {
        if self.path.is_empty() {
            key.to_string()
        } else {
            format!("{}.{key}", self.path)
        }
    }
}

impl<'de> DeserializeSeed<'de> for StrictValue<'_> {
    type Value = serde_json::Value;
    fn deserialize<De: Deserializer<'de>>(self, d: De) -> Result<serde_json::Value, De::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for StrictValue<'_> {
    type Value = serde_json::Value;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a JSON value")
    }
    fn visit_bool<E>(self, v: bool) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }
    fn visit_i64<E>(self, v: i64) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }
    fn visit_u64<E>(self, v: u64) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }
    fn visit_f64<E>(self, v: f64) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }
    fn visit_str<E>(self, v: &str) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }
    fn visit_string<E>(self, v: String) -> Result<serde_json::Value, E> {
        Ok(v.into())
    }
    fn visit_unit<E>(self) -> Result<serde_json::Value, E> {
        Ok(serde_json::Value::Null)
    }
    fn visit_none<E>(self) -> Result<serde_json::Value, E> {
        Ok(serde_json::Value::Null)
    }
    fn visit_some<De: Deserializer<'de>>(self, d: De) -> Result<serde_json::Value, De::Error> {
        self.deserialize(d)
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(
        self,
        mut seq: A,
    ) -> Result<serde_json::Value, A::Error> {
        let mut out = Vec::new();
        loop {
            let path = format!("{}[{}]", self.path, out.len());
            let next = seq.next_element_seed(StrictValue {
                path: path.clone(),
                at: self.at,
            });
            match next {
                Ok(Some(v)) => out.push(v),
                Ok(None) => return Ok(serde_json::Value::Array(out)),
                Err(e) => {
                    self.at.borrow_mut().get_or_insert(path);
                    return Err(e);
                }
            }
        }
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<serde_json::Value, A::Error> {
        let mut out = serde_json::Map::new();
        while let Some(key) = map.next_key::<String>()? {
            let path = self.child(&key);
            if out.contains_key(&key) {
                let e = serde::de::Error::custom(format_args!(
                    "duplicate field `{path}`: the key is given more than once"
                ));
                *self.at.borrow_mut() = Some(path);
                return Err(e);
            }
            let v = map.next_value_seed(StrictValue {
                path: path.clone(),
                at: self.at,
            });
            match v {
                Ok(v) => out.insert(key, v),
                Err(e) => {
                    self.at.borrow_mut().get_or_insert(path);
                    return Err(e);
                }
            };
        }
        Ok(serde_json::Value::Object(out))
    }
}

/// Rejects an array where the configuration type has a structure or a single value
/// (`reference`: the type's default, serialised): serde would read `"limits": [0.1, 0.5]` by
/// position, bypassing the key checks.
fn no_positional(
    v: &serde_json::Value,
    reference: &serde_json::Value,
    path: &str,
) -> Result<(), InputError> {
    use serde_json::Value;
    let name = |k: &str| {
        if path.is_empty() {
            k.to_string()
        } else {
            format!("{path}.{k}")
        }
    };
    match (v, reference) {
        (Value::Array(_), Value::Array(_)) => Ok(()),
        (Value::Array(_), r) => Err(InputError::Config {
            key: if path.is_empty() {
                "(top level)".into()
            } else {
                path.to_string()
            },
            reason: format!(
                "an array is not accepted here: expected {} (values are read by name, not by \
                 position)",
                match r {
                    Value::Object(_) => "an object of named keys",
                    Value::Null => "a single value or null",
                    _ => "a single value",
                }
            ),
        }),
        (Value::Object(m), Value::Object(r)) => {
            for (k, x) in m {
                if let Some(rx) = r.get(k) {
                    no_positional(x, rx, &name(k))?;
                }
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

/// serde would read a JSON array positionally into a configuration struct (`[100, 32]` as
/// `re = 100, n = 32`): only objects, whose keys are checked, are accepted.
fn not_an_object() -> InputError {
    InputError::Config {
        key: "(top level)".into(),
        reason: "a configuration must be a JSON object of named keys".into(),
    }
}

fn config_error(e: serde_path_to_error::Error<serde_json::Error>) -> InputError {
    let key = e.path().to_string();
    InputError::Config {
        // "." is the document itself, "?" a position serde could not name (end of input)
        key: if key == "." || key == "?" {
            "(top level)".into()
        } else {
            key
        },
        reason: e.into_inner().to_string(),
    }
}

// ---------------------------------------------------------------------------------------------
// the scene trait and the generic run

/// The ranges over a run of what the projection monitors every step: the semi-regularity
/// constant, connectivity, the closest particle approach, the Theorem 4.5 ratio and the
/// quantities that grow in a blow-up. Every scene's summary carries them (flattened).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MonitorRanges {
    /// Smallest `c0` over the steps.
    pub c0_min: f64,
    /// Largest `c0` over the steps.
    pub c0_max: f64,
    /// Smallest distance between a fluid particle and a neighbour over the steps
    /// ([`crate::projection::StepReport::min_spacing`]).
    pub min_spacing: f64,
    /// Most floating (pure Neumann) components in a step.
    pub max_floating: usize,
    /// Most isolated fluid particles in a step.
    pub max_isolated: usize,
    /// Steps in which the [`Disconnected::Float`] policy acted (fluid cut off from the rest).
    pub disconnected_steps: usize,
    /// Most fluid particles it acted on in a step.
    pub max_disconnected: usize,
    /// Largest Theorem 4.5 ratio (the theory bounds it by 1).
    pub max_stability_ratio: f64,
    /// Largest `‖∇̂h·uⁿ⁺¹‖ / ‖∇̂h·u*‖` (divergence after over before the projection; steps
    /// whose divergence before is at round-off, below `10⁻¹² max|u| / min spacing`, left out).
    pub max_div_ratio: f64,
    /// Largest `‖uⁿ⁺¹ − u*‖/‖u*‖` after the first ten steps (a flow started from rest is all
    /// correction at first).
    pub max_correction_ratio: f64,
    /// Largest kinetic-energy growth factor of a step after the first ten steps.
    pub max_energy_growth: f64,
    /// Moving particles: particles the wall margin stopped, summed over the steps
    /// ([`FlowReport::wall_pushes`]: a particle that would have come closer to a wall than the
    /// margin, its wall-normal motion stopped there).
    #[serde(default)]
    pub wall_pushes: usize,
    /// Steps in which the wall margin stopped a particle.
    #[serde(default)]
    pub wall_push_steps: usize,
    /// Largest RMS relative volume error the volume shift saw before a move
    /// ([`FlowReport::volume_error`]; `null` without a volume shift).
    #[serde(default)]
    pub max_volume_error: Option<f64>,
}

impl Default for MonitorRanges {
    fn default() -> Self {
        Self::new()
    }
}

impl MonitorRanges {
    /// Before the first step: empty ranges (`c0_min` and `min_spacing` at `∞`).
    pub fn new() -> Self {
        MonitorRanges {
            c0_min: f64::INFINITY,
            c0_max: 0.0,
            min_spacing: f64::INFINITY,
            max_floating: 0,
            max_isolated: 0,
            disconnected_steps: 0,
            max_disconnected: 0,
            max_stability_ratio: 0.0,
            max_div_ratio: 0.0,
            max_correction_ratio: 0.0,
            max_energy_growth: 0.0,
            wall_pushes: 0,
            wall_push_steps: 0,
            max_volume_error: None,
        }
    }

    /// Widens the ranges by one step's report.
    pub fn observe(&mut self, rep: &FlowReport) {
        let p = &rep.projection;
        self.c0_min = self.c0_min.min(p.c0);
        self.c0_max = self.c0_max.max(p.c0);
        self.min_spacing = self.min_spacing.min(p.min_spacing);
        self.max_floating = self.max_floating.max(p.connectivity.floating);
        self.max_isolated = self.max_isolated.max(p.connectivity.isolated);
        self.disconnected_steps += usize::from(p.disconnected > 0);
        self.max_disconnected = self.max_disconnected.max(p.disconnected);
        self.max_stability_ratio = self.max_stability_ratio.max(p.stability_ratio);
        // a divergence before at round-off (a flow without divergence, like the channel's)
        // gives a ratio of round-off: counted only above 10⁻¹² of the velocity-gradient scale
        let floor = 1e-12 * p.max_speed / p.min_spacing;
        if p.div_before > 0.0 && !(p.div_before <= floor) {
            self.max_div_ratio = self.max_div_ratio.max(p.div_after / p.div_before);
        }
        self.wall_pushes += rep.wall_pushes;
        self.wall_push_steps += usize::from(rep.wall_pushes > 0);
        if let Some(e) = rep.volume_error {
            self.max_volume_error = Some(self.max_volume_error.map_or(e, |m| m.max(e)));
        }
        if rep.step > 10 {
            self.max_correction_ratio = self.max_correction_ratio.max(p.correction_ratio);
            if let Some(g) = rep.energy_growth {
                self.max_energy_growth = self.max_energy_growth.max(g);
            }
        }
    }
}

/// A text table a scene produces at the end (e.g. `profile_u.csv`); the caller decides where
/// it goes ([`SceneRun::write_tables`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Table {
    /// File name (`profile_u.csv`).
    pub name: String,
    /// Contents (CSV text with a header line).
    pub text: String,
}

impl Table {
    /// A two-column CSV table `name` with the header `header` (`"T,Z"`) and one row per pair,
    /// numbers in their shortest exact form.
    pub fn pairs(name: &str, header: &str, rows: &[(f64, f64)]) -> Self {
        use std::fmt::Write;
        let mut text = format!("{header}\n");
        for (a, b) in rows {
            let _ = writeln!(text, "{a},{b}");
        }
        Table {
            name: name.into(),
            text,
        }
    }
}

/// A flow scene in `D` dimensions: how it is built from its configuration, what it observes
/// every step, and what it reports at the end. [`run_scene`] drives it.
pub trait Scene<const D: usize>: SceneParams {
    /// The boundary of its simulation.
    type Boundary: Boundary<D> + ToBoundarySpec<D> + Clone + 'static;
    /// What the scene accumulates over the steps (observables, samples).
    type State;
    /// The outcome of a run (printed by `gpm run` as `result`).
    type Result: Serialize + Clone + fmt::Debug;
    /// The flat summary written to `summary.json`.
    type Summary: Serialize;
    /// Shorten the last step so that the run lands on `t_end` exactly (the cavity instead
    /// stops at the first step past it).
    const LAND_ON_T_END: bool = false;

    /// Builds the simulation at `t = 0` (particles, boundary, parameters; ghosts, neighbours
    /// and volumes set up). Validates the configuration first.
    fn build(cfg: &SceneConfig<Self>) -> Result<Simulation<D, Self::Boundary>, Error>;
    /// The observables' state before the first step.
    fn start(cfg: &SceneConfig<Self>, sim: &Simulation<D, Self::Boundary>) -> Self::State;
    /// Called after every step; [`ControlFlow::Break`] ends the run (e.g. the cavity once
    /// steady and averaged).
    fn observe(
        state: &mut Self::State,
        cfg: &SceneConfig<Self>,
        report: &FlowReport,
        sim: &Simulation<D, Self::Boundary>,
    ) -> ControlFlow<()>;
    /// The result at the end of the run; `started` is when the run began (before `build`),
    /// for the wall-clock time.
    fn finish(
        state: Self::State,
        cfg: &SceneConfig<Self>,
        sim: &Simulation<D, Self::Boundary>,
        started: Instant,
    ) -> Self::Result;
    /// The summary of a result (for `summary.json`).
    fn summary(cfg: &SceneConfig<Self>, result: &Self::Result) -> Self::Summary;
    /// The tables of a result (none by default).
    fn tables(_cfg: &SceneConfig<Self>, _result: &Self::Result) -> Vec<Table> {
        Vec::new()
    }
    /// Writes the scene's PNG plots into `dir` (none by default).
    #[cfg(feature = "cli")]
    fn write_plots(
        _dir: &Path,
        _cfg: &SceneConfig<Self>,
        _result: &Self::Result,
        _sim: &Simulation<D, Self::Boundary>,
    ) -> Result<(), crate::plot::PlotError> {
        Ok(())
    }
}

/// How a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RunEnd {
    /// `t_end` reached.
    EndTime,
    /// The scene stopped it (e.g. the cavity, steady).
    Scene,
    /// The caller's observer stopped it after this step (e.g. Ctrl-C).
    Observer {
        /// Last step completed.
        step: u64,
    },
}

/// A finished run of scene `S`.
pub struct SceneRun<const D: usize, S: Scene<D>> {
    /// The scene's result.
    pub result: S::Result,
    /// The final state.
    pub sim: Simulation<D, S::Boundary>,
    /// How the run ended.
    pub end: RunEnd,
}

impl<const D: usize, S: Scene<D>> SceneRun<D, S> {
    /// Whether the caller's observer stopped the run.
    pub fn interrupted(&self) -> Option<u64> {
        match self.end {
            RunEnd::Observer { step } => Some(step),
            _ => None,
        }
    }

    /// The summary (`summary.json`).
    pub fn summary(&self, cfg: &SceneConfig<S>) -> S::Summary {
        S::summary(cfg, &self.result)
    }

    /// Writes the scene's tables and `summary.json` (pretty JSON) into `dir` (created if
    /// missing); returns the files written. Each file is written under a temporary name and
    /// renamed when complete ([`write_atomic`](crate::record::output::write_atomic)); a table
    /// holding a value that is not finite (`NaN`, `inf`) is refused (an
    /// [`std::io::ErrorKind::InvalidData`] error naming the file, row and column) and nothing
    /// more is written; non-finite numbers in the summary are written as `null`.
    pub fn write_tables(
        &self,
        dir: &Path,
        cfg: &SceneConfig<S>,
    ) -> std::io::Result<Vec<std::path::PathBuf>> {
        use crate::record::output::write_atomic;
        std::fs::create_dir_all(dir)?;
        let tables = S::tables(cfg, &self.result);
        for t in &tables {
            check_finite_table(t)?;
        }
        let mut written = Vec::new();
        for t in tables {
            let path = dir.join(&t.name);
            write_atomic(&path, t.text.as_bytes())?;
            written.push(path);
        }
        let path = dir.join("summary.json");
        let text =
            serde_json::to_string_pretty(&self.summary(cfg)).map_err(std::io::Error::other)?;
        write_atomic(&path, text.as_bytes())?;
        written.push(path);
        Ok(written)
    }

    /// Writes the scene's plots into `dir`.
    #[cfg(feature = "cli")]
    pub fn write_plots(
        &self,
        dir: &Path,
        cfg: &SceneConfig<S>,
    ) -> Result<(), crate::plot::PlotError> {
        S::write_plots(dir, cfg, &self.result, &self.sim)
    }
}

/// Refuses a CSV table with a cell that is not a finite number (`NaN`, `inf`, …).
fn check_finite_table(t: &Table) -> std::io::Result<()> {
    for (row, line) in t.text.lines().enumerate() {
        for (col, cell) in line.split(',').enumerate() {
            let c = cell.trim();
            if c.parse::<f64>().is_ok_and(|v| !v.is_finite()) {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!(
                        "{}: line {} column {}: '{c}' is not finite; the table is not written",
                        t.name,
                        row + 1,
                        col + 1
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// What an observer returns: go on, or stop the run after this step (not an error: the run
/// still finishes and reports its result, with [`RunEnd::Observer`]).
pub type Observed = Result<ControlFlow<()>, Error>;

/// How the steps of a scene's run are taken ([`run_scene_with`]): by its simulation in this
/// process ([`OneProcess`]), or by a run decomposed over several ranks that keeps the scene's
/// simulation as the gathered copy the scene observes and a recording writes
/// ([`ranks::Decomposed`]).
pub trait Stepper<const D: usize, B: Boundary<D>> {
    /// Called once with the built simulation, after the caller's setup and before the first
    /// step.
    fn start(&mut self, _sim: &mut Simulation<D, B>) -> Result<(), Error> {
        Ok(())
    }
    /// One step (ending at `until` at the latest, as [`Simulation::advance_toward`]); after it
    /// `sim` holds the state the scene observes.
    fn step(&mut self, sim: &mut Simulation<D, B>, until: Option<f64>)
        -> Result<FlowReport, Error>;
    /// The decisions taken after a step, the same in every process (collective): the scene's
    /// stop as the observing process decided it, the caller's stop and an observer's failure
    /// if any process had one. One process: as given.
    fn agree(&mut self, votes: Votes) -> Votes {
        votes
    }
}

/// What the processes of a run decided after a step ([`Stepper::agree`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Votes {
    /// The scene ends the run ([`Scene::observe`]).
    pub scene_stop: bool,
    /// The caller's observer ends the run.
    pub caller_stop: bool,
    /// The caller's observer failed.
    pub failed: bool,
}

/// The steps of a run in this process: [`Simulation::advance`] (or
/// [`Simulation::advance_toward`] for a scene that lands on its end time).
#[derive(Clone, Copy, Debug, Default)]
pub struct OneProcess;

impl<const D: usize, B: Boundary<D>> Stepper<D, B> for OneProcess {
    fn step(
        &mut self,
        sim: &mut Simulation<D, B>,
        until: Option<f64>,
    ) -> Result<FlowReport, Error> {
        match until {
            Some(t) => sim.advance_toward(t),
            None => sim.advance(),
        }
    }
}

/// Runs scene `S`: builds it, lets `setup` adjust the simulation before the first step (e.g.
/// `sim.projection.capture = true`, a perturbation), then steps until `t_end` (landing on it
/// exactly when [`Scene::LAND_ON_T_END`]), until the scene's [`Scene::observe`] or the
/// caller's `observer` returns [`ControlFlow::Break`], or until an error. The scene observes a
/// step before the caller's observer does.
pub fn run_scene<const D: usize, S: Scene<D>>(
    cfg: &SceneConfig<S>,
    setup: impl FnOnce(&mut Simulation<D, S::Boundary>),
    observer: impl FnMut(&FlowReport, &Simulation<D, S::Boundary>) -> Observed,
) -> Result<SceneRun<D, S>, Error> {
    run_scene_with(cfg, &mut OneProcess, setup, observer)
}

/// [`run_scene`] with its steps taken by `stepper` (e.g. [`ranks::Decomposed`]: the run
/// decomposed over the ranks of `mpirun`, every rank calling this with the same
/// configuration). The scene and `observer` see the simulation the stepper leaves after each
/// step; the stops and an observer's failure are agreed by the stepper's processes (another
/// process's failure is [`Error::PeerFailed`] here).
pub fn run_scene_with<const D: usize, S: Scene<D>>(
    cfg: &SceneConfig<S>,
    stepper: &mut impl Stepper<D, S::Boundary>,
    setup: impl FnOnce(&mut Simulation<D, S::Boundary>),
    mut observer: impl FnMut(&FlowReport, &Simulation<D, S::Boundary>) -> Observed,
) -> Result<SceneRun<D, S>, Error> {
    let started = Instant::now();
    let mut sim = S::build(cfg)?;
    if let Some(path) = &cfg.initial {
        let snap = warm_start::FluidSnapshot::read(path)?;
        warm_start::apply(&mut sim, &snap)?;
    }
    setup(&mut sim);
    let mut state = S::start(cfg, &sim);
    let mut end = RunEnd::EndTime;
    if !(sim.time < cfg.t_end - 1e-12) {
        // no step would be taken: the "result" would be the initial field's
        return Err(InputError::parameter(
            "t_end",
            cfg.t_end,
            format!(
                "the run would take no step (it starts at t = {}): nothing to report",
                sim.time
            ),
        )
        .into());
    }
    stepper.start(&mut sim)?;
    let until = S::LAND_ON_T_END.then_some(cfg.t_end);
    while sim.time < cfg.t_end - 1e-12 {
        let rep = stepper.step(&mut sim, until)?;
        let scene = S::observe(&mut state, cfg, &rep, &sim);
        let observed = observer(&rep, &sim);
        let votes = stepper.agree(Votes {
            scene_stop: scene.is_break(),
            caller_stop: matches!(observed, Ok(ControlFlow::Break(()))),
            failed: observed.is_err(),
        });
        let _: ControlFlow<()> = observed?;
        if votes.failed {
            return Err(Error::PeerFailed {
                step: rep.step,
                ranks: 1,
            });
        }
        if votes.caller_stop {
            end = RunEnd::Observer { step: rep.step };
            break;
        }
        if votes.scene_stop {
            end = RunEnd::Scene;
            break;
        }
    }
    let result = S::finish(state, cfg, &sim, started);
    Ok(SceneRun { result, sim, end })
}

/// A run with its recording: the run's outcome and the recording's, both known after the file
/// was finished.
pub struct RecordedRun<const D: usize, S: Scene<D>> {
    /// The run (an error is the run's failure; every step before it is in the file).
    pub run: Result<SceneRun<D, S>, Error>,
    /// The finished recording (its `path` says where it went).
    pub record: Result<RecordSummary, RecordError>,
    /// The output directory's lock, held until this is dropped, so that the caller's own files
    /// (tables, plots) are written while the directory is still its own.
    pub lock: OutputLock,
}

/// [`run_scene`] recording every step into `path` ([`Recorder`]; the `/config` message is
/// `header`, usually [`SceneConfig::record_header`]). At [`RecordLevel::Full`] the projection
/// inputs are captured. The file is finished whatever happened, so every step before a failure
/// or a stop reads back.
///
/// The run owns the directory of `path`: it takes an [`OutputLock`] there first (another run
/// holding it is a [`RecordError::Locked`] naming its process id, before anything is written)
/// and hands it back in [`RecordedRun::lock`]. The file is written as `path.partial` and renamed
/// to `path` when the run ended without an error (end time, the scene's stop, the observer's
/// stop); a failed run's file is kept as `run.failed.mcap` ([`Recorder::finish_failed`]), so a
/// good earlier recording at `path` survives. Fails only when the directory is locked or the
/// file cannot be created.
pub fn run_recorded<const D: usize, S: Scene<D>>(
    cfg: &SceneConfig<S>,
    path: &Path,
    options: RecorderOptions,
    header: &serde_json::Value,
    setup: impl FnOnce(&mut Simulation<D, S::Boundary>),
    observer: impl FnMut(&FlowReport, &Simulation<D, S::Boundary>) -> Observed,
) -> Result<RecordedRun<D, S>, RecordError> {
    run_recorded_with(cfg, &mut OneProcess, path, options, header, setup, observer)
}

/// [`run_recorded`] with its steps taken by `stepper` ([`run_scene_with`]): the process that
/// calls this records what the scene observes (with [`ranks::Decomposed`], rank 0 holds the
/// gathered copy and records; the other ranks call [`run_scene_with`]).
pub fn run_recorded_with<const D: usize, S: Scene<D>>(
    cfg: &SceneConfig<S>,
    stepper: &mut impl Stepper<D, S::Boundary>,
    path: &Path,
    options: RecorderOptions,
    header: &serde_json::Value,
    setup: impl FnOnce(&mut Simulation<D, S::Boundary>),
    mut observer: impl FnMut(&FlowReport, &Simulation<D, S::Boundary>) -> Observed,
) -> Result<RecordedRun<D, S>, RecordError> {
    let capture = options.level == RecordLevel::Full;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let lock = OutputLock::acquire(dir)?;
    let mut rec = Recorder::create_with(path, options, header)?;
    let run = run_scene_with(
        cfg,
        stepper,
        |sim| {
            sim.projection.capture = capture;
            setup(sim)
        },
        |rep, sim| {
            rec.write_step(rep, sim)?;
            observer(rep, sim)
        },
    );
    let record = if run.is_ok() {
        rec.finish()
    } else {
        rec.finish_failed()
    };
    Ok(RecordedRun { run, record, lock })
}

// ---------------------------------------------------------------------------------------------
// registry

/// Something done with a scene type chosen by name ([`visit_scene`]): `gpm run` reads, runs
/// and records the scene the user named through one generic `visit`.
pub trait SceneVisitor {
    /// What the visit returns.
    type Output;
    /// Called with the named scene's type.
    fn visit<const D: usize, S: Scene<D>>(self) -> Self::Output;
}

/// The registry: one line per scene (`dimension => type`).
macro_rules! registry {
    ($($d:literal => $scene:ty),* $(,)?) => {
        /// The registered scenes' names.
        pub const SCENES: &[&str] = &[$(<$scene as SceneParams>::NAME),*];

        /// Calls `visitor` with the scene named `name` (`taylor-green` and `taylor_green` are
        /// the same); an unknown name is a [`InputError::Config`] on the key `scene` listing
        /// the known ones.
        pub fn visit_scene<V: SceneVisitor>(name: &str, visitor: V) -> Result<V::Output, InputError> {
            let name = name.trim().to_ascii_lowercase().replace('-', "_");
            $(
                if name == <$scene as SceneParams>::NAME {
                    return Ok(visitor.visit::<$d, $scene>());
                }
            )*
            Err(InputError::Config {
                key: "scene".into(),
                reason: format!("unknown scene '{name}': expected one of {}", SCENES.join(", ")),
            })
        }
    };
}

registry! {
    2 => cavity::Cavity,
    2 => taylor_green::TaylorGreen,
    2 => channel::Channel,
    2 => hydrostatic::Hydrostatic,
    2 => dam_break::DamBreak,
    3 => cube::Cube,
    3 => dam_break_3d::DamBreak3d,
}
