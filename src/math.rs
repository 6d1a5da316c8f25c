//! Small fixed-size vector helpers over `[f64; D]`, and [`in_pool`] for the entry points that run
//! many parallel loops.
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

/// Runs `f` on a thread of rayon's pool (at once when already on one). A parallel loop started
/// from outside the pool is sent to it and waited for — a futex wake-up and sleep per loop;
/// the entry points that run hundreds of loops (a flow step, a projection, a prediction) go
/// through this so that those loops split inside the pool instead. Measured with perf on the
/// Lagrangian cavity at 2 500 particles and one thread: the step took 52 ms, a third of it in
/// those wake-ups, and 27 ms from a pool thread.
pub fn in_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    if rayon::current_thread_index().is_some() {
        f()
    } else {
        rayon::scope(|_| f())
    }
}
