//! [`Comm`] over MPI (rsmpi on the system's Open MPI; feature `mpi`).

use super::comm::Comm;
use mpi::collective::CommunicatorCollectives;
use mpi::datatype::PartitionMut;
use mpi::point_to_point::{Destination, Source};
use mpi::topology::{Communicator, SimpleCommunicator};
use mpi::Count;

/// The MPI world. Holds no handle (every call asks for the world communicator), so it is
/// `Send + Sync`; MPI must be initialised (with at least `Threading::Serialized`: the step may
/// call from a rayon thread) for as long as it is used, see [`init`].
#[derive(Clone, Copy, Debug, Default)]
pub struct MpiComm;

/// Initialises MPI with `Threading::Serialized` (one thread at a time, not necessarily the
/// main one); `None` when MPI was initialised already or is not available. Keep the
/// `Universe` alive until the end: dropping it finalises MPI.
pub fn init() -> Option<mpi::environment::Universe> {
    mpi::initialize_with_threading(mpi::Threading::Serialized).map(|(u, _)| u)
}

fn world() -> SimpleCommunicator {
    SimpleCommunicator::world()
}

impl Comm for MpiComm {
    fn rank(&self) -> usize {
        world().rank() as usize
    }
    fn size(&self) -> usize {
        world().size() as usize
    }
    fn all_gather(&self, local: &[f64]) -> Vec<Vec<f64>> {
        let w = world();
        let p = w.size() as usize;
        let mut counts = vec![0 as Count; p];
        w.all_gather_into(&(local.len() as Count), &mut counts[..]);
        let displs: Vec<Count> = counts
            .iter()
            .scan(0, |acc, &c| {
                let d = *acc;
                *acc += c;
                Some(d)
            })
            .collect();
        let total: Count = counts.iter().sum();
        let mut buf = vec![0.0f64; total as usize];
        {
            let mut part = PartitionMut::new(&mut buf[..], &counts[..], &displs[..]);
            w.all_gather_varcount_into(local, &mut part);
        }
        (0..p)
            .map(|q| {
                let s = displs[q] as usize;
                buf[s..s + counts[q] as usize].to_vec()
            })
            .collect()
    }
    fn exchange(&self, sends: &[(usize, Vec<f64>)], recvs: &mut [(usize, Vec<f64>)]) {
        let w = world();
        mpi::request::scope(|scope| {
            let requests: Vec<_> = sends
                .iter()
                .map(|(q, data)| {
                    w.process_at_rank(*q as i32)
                        .immediate_send(scope, &data[..])
                })
                .collect();
            for (q, buf) in recvs.iter_mut() {
                w.process_at_rank(*q as i32).receive_into(&mut buf[..]);
            }
            for r in requests {
                r.wait();
            }
        });
    }
}
