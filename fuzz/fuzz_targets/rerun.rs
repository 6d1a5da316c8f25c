//! The re-run path (`gpm replay --rerun`): recorded projection inputs → `rerun_input`. Two
//! modes, chosen by the first byte: (even) the rest is a `/projection_input` message's JSON,
//! decoded and re-run as `gpm replay --rerun` would; (odd) the rest is a list of corruptions
//! `(field, index, value)` applied to a valid recorded input of a small cavity or Taylor–Green
//! step (roles, ghost sources and walls, positions, volumes, walls, `h`, `dt`, dimension), which
//! reaches the checks far more often than mutated base64. Every outcome must be a comparison or
//! a typed error, never a panic, a hang or an unbounded allocation.
#![no_main]

use gpm::record::replay::scan;
use gpm::record::rerun::rerun_input;
use gpm::record::schema::{Array, BoundarySpec, ProjectionInput, TOPIC_PROJECTION};
use gpm::record::{RecordLevel, Recorder};
use gpm::scene::{cavity, taylor_green};
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;

/// A recorded input of one step of a small cavity (walls) and Taylor–Green (periodic) run.
fn bases() -> &'static [ProjectionInput; 2] {
    static BASES: OnceLock<[ProjectionInput; 2]> = OnceLock::new();
    BASES.get_or_init(|| {
        let dir = std::env::temp_dir();
        let record = |walls: bool| {
            let path = dir.join(format!(
                "gpm-fuzz-rerun-{}-{walls}.mcap",
                std::process::id()
            ));
            let mut rec = Recorder::create(&path, RecordLevel::Full, 1, &()).expect("recorder");
            if walls {
                let cfg = cavity::CavityConfig::default().with(|c| c.n = 6);
                let mut sim = cavity::build(&cfg).expect("cavity");
                sim.projection.capture = true;
                let r = sim.advance().expect("step");
                rec.write_step(&r, &sim).expect("record");
            } else {
                let cfg = taylor_green::TaylorGreenConfig::default().with(|c| c.n = 8);
                let mut sim = taylor_green::build(&cfg).expect("taylor-green");
                sim.projection.capture = true;
                let r = sim.advance().expect("step");
                rec.write_step(&r, &sim).expect("record");
            }
            rec.finish().expect("finish");
            let mut first = None;
            scan(
                &path,
                |m| {
                    if m.topic == TOPIC_PROJECTION && first.is_none() {
                        first = Some(m.decode::<ProjectionInput>()?);
                    }
                    Ok(())
                },
                |_, _| {},
            )
            .expect("scan");
            let _ = std::fs::remove_file(&path);
            first.expect("a projection input")
        };
        [record(true), record(false)]
    })
}

fn f64_at(bytes: &[u8]) -> f64 {
    let mut b = [0u8; 8];
    for (d, s) in b.iter_mut().zip(bytes) {
        *d = *s;
    }
    f64::from_le_bytes(b)
}

fn corrupt(m: &mut ProjectionInput, ops: &[u8]) {
    for op in ops.chunks(11) {
        if op.len() < 11 {
            return;
        }
        let (field, idx, val) = (op[0], u16::from_le_bytes([op[1], op[2]]) as usize, &op[3..]);
        let n = m.particles.max(1);
        let i = idx % n;
        let v = f64_at(val);
        let w = u32::from_le_bytes([val[0], val[1], val[2], val[3]]);
        match field % 12 {
            0 => {
                let Ok(mut k) = m.role_kind.to_u8("k") else {
                    return;
                };
                if let Some(x) = k.get_mut(i) {
                    *x = val[0] % 4;
                }
                m.role_kind = Array::from_u8(&k);
            }
            1 => {
                let Ok(mut s) = m.ghost_source.to_u32("s") else {
                    return;
                };
                if let Some(x) = s.get_mut(i) {
                    *x = w;
                }
                m.ghost_source = Array::from_u32(&s);
            }
            2 => {
                let Ok(mut s) = m.ghost_walls.to_u8("w") else {
                    return;
                };
                if let Some(x) = s.get_mut(i) {
                    *x = val[0];
                }
                m.ghost_walls = Array::from_u8(&s);
            }
            3 | 4 => {
                let arr = if field % 12 == 3 {
                    &mut m.x
                } else {
                    &mut m.u_star
                };
                let Ok(mut x) = arr.to_f64("x") else { return };
                let len = x.len().max(1);
                if let Some(c) = x.get_mut(idx % len) {
                    *c = v;
                }
                *arr = Array {
                    shape: arr.shape.clone(),
                    ..Array::from_f64(&x)
                };
            }
            5 => {
                let Ok(mut x) = m.vol.to_f64("vol") else {
                    return;
                };
                if let Some(c) = x.get_mut(i) {
                    *c = v;
                }
                m.vol = Array::from_f64(&x);
            }
            6 => m.neighbors.h = v,
            7 => m.neighbors.skin = v,
            8 => m.dt = v,
            9 => m.dimension = val[0] as usize % 5,
            10 => {
                if let BoundarySpec::Walls { walls, .. } = &mut m.boundary {
                    if walls.is_empty() {
                        continue;
                    }
                    let k = idx % walls.len();
                    match val[0] % 4 {
                        0 => walls[k].axis = val[1] as usize,
                        1 => walls[k].position = f64_at(&val[1..]),
                        2 => walls[k].inward = f64_at(&val[1..]),
                        _ => walls[k].velocity.truncate(val[1] as usize % 3),
                    }
                }
            }
            _ => {
                // drop or duplicate the last particle's entries in one array
                let Ok(mut p) = m.p_in.to_f64("p") else {
                    return;
                };
                if val[0] % 2 == 0 {
                    p.pop();
                } else if let Some(&l) = p.last() {
                    p.push(l);
                }
                m.p_in = Array::from_f64(&p);
            }
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    if mode % 2 == 0 {
        let Ok(m) = serde_json::from_slice::<ProjectionInput>(rest) else {
            return;
        };
        // the harness bounds the work (a recorded input may hold millions of particles)
        if m.particles > 4096 || m.x.data.len() > 1 << 20 {
            return;
        }
        let _ = rerun_input(&m).map_err(|e| e.to_string());
    } else {
        let base = &bases()[(mode as usize / 2) % 2];
        let mut m = base.clone();
        corrupt(&mut m, rest);
        let _ = rerun_input(&m).map_err(|e| e.to_string());
    }
});
