//! Scene configuration parsing: arbitrary bytes → JSON → `CavityConfig` / `TaylorGreenConfig`
//! (`gpm::scene::config_from_json`, unknown keys rejected) → `validate` → `build` at a tiny
//! resolution → one step. Every failure must be a typed error, never a panic, a hang or an
//! unbounded allocation.
#![no_main]

use gpm::scene::{cavity, config_from_json, taylor_green};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&selector, rest)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    if selector % 2 == 0 {
        let Ok(mut cfg) = config_from_json::<cavity::CavityConfig>(text) else {
            return;
        };
        if cfg.validate().is_err() {
            return;
        }
        // the harness keeps the run tiny (the configuration may ask for 20 000² particles or
        // 10⁹ CG iterations, which are valid but not what a fuzzer can afford)
        cfg.n = 4 + cfg.n % 9;
        cfg.solve.max_iters = cfg.solve.max_iters.min(200);
        if let Ok(mut sim) = cavity::build(&cfg) {
            let _ = sim.advance();
        }
    } else {
        let Ok(mut cfg) = config_from_json::<taylor_green::TaylorGreenConfig>(text) else {
            return;
        };
        if cfg.validate().is_err() {
            return;
        }
        cfg.n = 8 + cfg.n % 5;
        cfg.solve.max_iters = cfg.solve.max_iters.min(200);
        if let Ok(mut sim) = taylor_green::build(&cfg) {
            let _ = sim.advance();
        }
    }
});
