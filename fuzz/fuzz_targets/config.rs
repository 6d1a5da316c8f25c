//! Scene configuration parsing: arbitrary bytes → JSON → `CavityConfig` / `TaylorGreenConfig`
//! → `validate` → the run estimates → `build` at a tiny resolution → one step. The selector
//! byte picks the scene and the path: the library's `config_from_json`, or the command line's
//! `scene_config_from_json` (`gpm run <scene> --config FILE`: a bare configuration or a
//! recording's `{"scene", "config"}`, duplicate keys and positional arrays rejected). Every
//! failure must be a typed error, never a panic, a hang or an unbounded allocation.
#![no_main]

use gpm::scene::{
    cavity, config_from_json, scene_config_from_json, strict_json, taylor_green, SceneConfig,
    SceneParams,
};
use libfuzzer_sys::fuzz_target;

fn parse<S: SceneParams>(text: &str, cli: bool) -> Option<SceneConfig<S>> {
    let cfg = if cli {
        scene_config_from_json::<S>(text)
    } else {
        config_from_json::<SceneConfig<S>>(text)
    };
    match cfg {
        Ok(c) => Some(c),
        Err(e) => {
            let _ = e.to_string();
            None
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&selector, rest)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    let cli = selector & 2 != 0;
    if selector & 4 != 0 {
        let _ = strict_json(text).map_err(|e| e.to_string());
    }
    if selector % 2 == 0 {
        let Some(mut cfg) = parse::<cavity::Cavity>(text, cli) else {
            return;
        };
        if cfg.validate().is_err() {
            return;
        }
        let _ = cfg.memory_estimate::<2>();
        // the harness keeps the run tiny (the configuration may ask for 10 000² particles or
        // 10⁹ CG iterations, which are valid but not what a fuzzer can afford)
        cfg.n = 4 + cfg.n % 9;
        cfg.solve.max_iters = cfg.solve.max_iters.min(200);
        if let Ok(mut sim) = cavity::build(&cfg) {
            let _ = sim.time_step();
            let _ = sim.advance();
        }
    } else {
        let Some(mut cfg) = parse::<taylor_green::TaylorGreen>(text, cli) else {
            return;
        };
        if cfg.validate().is_err() {
            return;
        }
        let _ = cfg.memory_estimate::<2>();
        cfg.n = 8 + cfg.n % 5;
        cfg.solve.max_iters = cfg.solve.max_iters.min(200);
        if let Ok(mut sim) = taylor_green::build(&cfg) {
            let _ = sim.time_step();
            let _ = sim.advance();
        }
    }
});
