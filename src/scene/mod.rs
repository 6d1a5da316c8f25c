//! Ready-made scenes.

pub mod cavity;
pub mod taylor_green;

use crate::error::InputError;
use serde::de::DeserializeOwned;

/// Reads a scene configuration ([`cavity::CavityConfig`], [`taylor_green::TaylorGreenConfig`])
/// from JSON text. Unknown keys and ill-typed values are rejected with an
/// [`InputError::Config`] naming the key (`limits.cfl`, `n`; `(top level)` for the document
/// itself); the values are checked by the configuration's own `validate`, which the scene's
/// `build` calls.
///
/// ```
/// use gpm::error::InputError;
/// use gpm::scene::{cavity::CavityConfig, config_from_json};
///
/// let cfg: CavityConfig = config_from_json(r#"{"re": 400, "n": 32}"#)?;
/// assert_eq!((cfg.re, cfg.n), (400.0, 32));
/// match config_from_json::<CavityConfig>(r#"{"limits": {"cfl": "fast"}}"#) {
///     Err(InputError::Config { key, .. }) => assert_eq!(key, "limits.cfl"),
///     other => panic!("{other:?}"),
/// }
/// # Ok::<(), InputError>(())
/// ```
pub fn config_from_json<T: DeserializeOwned>(text: &str) -> Result<T, InputError> {
    if !text.trim_start().starts_with('{') {
        return Err(not_an_object());
    }
    let mut de = serde_json::Deserializer::from_str(text);
    let value: T = serde_path_to_error::deserialize(&mut de).map_err(config_error)?;
    de.end().map_err(|e| InputError::Config {
        key: "(top level)".into(),
        reason: e.to_string(),
    })?;
    Ok(value)
}

/// [`config_from_json`] for an already parsed JSON value (e.g. the `config` member of a
/// recorded `/config` message).
pub fn config_from_value<T: DeserializeOwned>(value: serde_json::Value) -> Result<T, InputError> {
    if !value.is_object() {
        return Err(not_an_object());
    }
    serde_path_to_error::deserialize(value).map_err(config_error)
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

/// Checks shared by the scene configurations: the linear-solver tolerances and iteration limit
/// and the shifting parameters, naming the first bad one.
pub(crate) fn validate_common(
    solve: &crate::poisson::SolveParams,
    shifting: Option<&crate::flow::Shifting>,
) -> Result<(), InputError> {
    let bad = |name: &'static str, value: f64, reason: &str| {
        Err(InputError::Parameter {
            name: name.into(),
            value,
            reason: reason.into(),
        })
    };
    if !(solve.rel_tol >= 0.0 && solve.rel_tol.is_finite()) {
        return bad(
            "solve.rel_tol",
            solve.rel_tol,
            "must be non-negative and finite",
        );
    }
    if !(solve.abs_tol >= 0.0 && solve.abs_tol.is_finite()) {
        return bad(
            "solve.abs_tol",
            solve.abs_tol,
            "must be non-negative and finite",
        );
    }
    if solve.max_iters == 0 {
        return bad("solve.max_iters", 0.0, "at least one iteration is needed");
    }
    if let Some(s) = shifting {
        if !(s.coefficient >= 0.0 && s.coefficient.is_finite()) {
            return bad(
                "shifting.coefficient",
                s.coefficient,
                "must be non-negative and finite",
            );
        }
        if !(s.max_fraction >= 0.0 && s.max_fraction <= 1.0) {
            return bad("shifting.max_fraction", s.max_fraction, "must be in [0, 1]");
        }
    }
    Ok(())
}
