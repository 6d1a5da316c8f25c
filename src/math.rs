//! Small fixed-size vector helpers over `[f64; D]`.
//!
//! Particle state is stored as `Vec<[f64; D]>` so that kiddo, faer and rayon can all borrow it
//! without copies; these helpers keep the arithmetic on those arrays readable.

/// The one scalar type of the crate.
pub type Real = f64;

/// A point or vector in `D` dimensions.
pub type Vector<const D: usize> = [f64; D];

/// `a · b`.
#[inline(always)]
pub fn dot<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    let mut s = 0.0;
    for k in 0..D {
        s += a[k] * b[k];
    }
    s
}

/// `|a|²`.
#[inline(always)]
pub fn norm2<const D: usize>(a: &[f64; D]) -> f64 {
    dot(a, a)
}

/// `a − b`.
#[inline(always)]
pub fn sub<const D: usize>(a: &[f64; D], b: &[f64; D]) -> [f64; D] {
    std::array::from_fn(|k| a[k] - b[k])
}

/// `a + b`.
#[inline(always)]
pub fn add<const D: usize>(a: &[f64; D], b: &[f64; D]) -> [f64; D] {
    std::array::from_fn(|k| a[k] + b[k])
}

/// `s a`.
#[inline(always)]
pub fn scale<const D: usize>(s: f64, a: &[f64; D]) -> [f64; D] {
    std::array::from_fn(|k| s * a[k])
}

/// `a + s b`.
#[inline(always)]
pub fn axpy<const D: usize>(a: &[f64; D], s: f64, b: &[f64; D]) -> [f64; D] {
    std::array::from_fn(|k| a[k] + s * b[k])
}

/// True when every component is finite.
#[inline(always)]
pub fn is_finite<const D: usize>(a: &[f64; D]) -> bool {
    a.iter().all(|v| v.is_finite())
}
