//! The few collective operations the distributed solve needs, behind a trait: MPI
//! (`distributed::mpi::MpiComm`, feature `mpi`) or threads of one process ([`ThreadComm`], for the
//! tests that run without MPI).

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Condvar, Mutex};

/// A group of ranks. Every rank calls the collective operations in the same order.
pub trait Comm: Send + Sync + std::fmt::Debug {
    /// This rank, `0..size`.
    fn rank(&self) -> usize;
    /// Number of ranks.
    fn size(&self) -> usize;
    /// Every rank's `local`, in rank order (the counts may differ between ranks).
    fn all_gather(&self, local: &[f64]) -> Vec<Vec<f64>>;
    /// Point-to-point exchange with neighbours: `sends[k].1` goes to rank `sends[k].0`, and
    /// `recvs[k].1` (whose length is the count expected) is filled from rank `recvs[k].0`.
    fn exchange(&self, sends: &[(usize, Vec<f64>)], recvs: &mut [(usize, Vec<f64>)]);

    /// Element-wise sum over the ranks, added in rank order, so that every rank gets the same
    /// bits and a run gives the same bits every time (an allgather of the partial sums).
    fn sum(&self, local: &[f64]) -> Vec<f64> {
        let all = self.all_gather(local);
        let mut out = vec![0.0; local.len()];
        for part in &all {
            for (o, v) in out.iter_mut().zip(part) {
                *o += v;
            }
        }
        out
    }

    /// What each rank receives, from what each sends: `counts[q]` is how many items this rank
    /// sends to rank `q`; the result's `[q]` is how many it receives from `q` (one all-gather
    /// of `P` numbers per rank: the lengths that [`Self::exchange`] needs to know).
    fn transpose_counts(&self, counts: &[usize]) -> Vec<usize> {
        let me = self.rank();
        let local: Vec<f64> = counts.iter().map(|&c| c as f64).collect();
        self.all_gather(&local)
            .into_iter()
            .map(|row| row[me] as usize)
            .collect()
    }

    /// Element-wise maximum over the ranks.
    fn max(&self, local: &[f64]) -> Vec<f64> {
        let all = self.all_gather(local);
        let mut out = vec![f64::NEG_INFINITY; local.len()];
        for part in &all {
            for (o, v) in out.iter_mut().zip(part) {
                *o = o.max(*v);
            }
        }
        out
    }
}

/// One process as the only rank.
#[derive(Clone, Copy, Debug, Default)]
pub struct SelfComm;

impl Comm for SelfComm {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn all_gather(&self, local: &[f64]) -> Vec<Vec<f64>> {
        vec![local.to_vec()]
    }
    fn exchange(&self, sends: &[(usize, Vec<f64>)], recvs: &mut [(usize, Vec<f64>)]) {
        assert!(
            sends.is_empty() && recvs.is_empty(),
            "one rank has no neighbours"
        );
    }
}

#[derive(Debug, Default)]
struct Mailboxes {
    /// Messages from → to, in the order sent.
    queues: HashMap<(usize, usize), VecDeque<Vec<f64>>>,
    /// Ranks whose thread has ended (returned or panicked): a receive from one of them that
    /// finds no message fails instead of waiting for ever.
    ended: std::collections::HashSet<usize>,
}

/// Marks its rank ended when dropped (at the end of the rank's thread, also by a panic).
struct Ended(ThreadComm);

impl Drop for Ended {
    fn drop(&mut self) {
        let (lock, cv) = &*self.0.shared;
        // a poisoned lock still holds the mailboxes
        let mut g = lock.lock().unwrap_or_else(|e| e.into_inner());
        g.ended.insert(self.0.rank);
        cv.notify_all();
    }
}

/// Ranks as threads of one process (messages through shared queues): the distributed
/// algorithms tested by the ordinary `cargo test`, without MPI.
#[derive(Clone, Debug)]
pub struct ThreadComm {
    rank: usize,
    size: usize,
    shared: Arc<(Mutex<Mailboxes>, Condvar)>,
}

impl ThreadComm {
    /// Runs `f` on `size` threads, one rank each, and returns their results in rank order.
    /// Each rank runs inside its own one-thread rayon pool, as an MPI rank runs in its own
    /// process: ranks that block in a collective must not hold the threads of a shared pool
    /// that the other ranks' work is queued on (a flow step runs inside the pool,
    /// [`crate::math::in_pool`]).
    pub fn run<R: Send>(size: usize, f: impl Fn(ThreadComm) -> R + Sync) -> Vec<R> {
        let shared = Arc::new((Mutex::new(Mailboxes::default()), Condvar::new()));
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..size)
                .map(|rank| {
                    let comm = ThreadComm {
                        rank,
                        size,
                        shared: shared.clone(),
                    };
                    let f = &f;
                    s.spawn(move || {
                        let _ended = Ended(comm.clone());
                        match rayon::ThreadPoolBuilder::new().num_threads(1).build() {
                            Ok(pool) => pool.install(|| f(comm)),
                            Err(_) => f(comm),
                        }
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("rank thread panicked"))
                .collect()
        })
    }

    fn send(&self, to: usize, data: Vec<f64>) {
        let (lock, cv) = &*self.shared;
        lock.lock()
            .unwrap_or_else(|e| e.into_inner())
            .queues
            .entry((self.rank, to))
            .or_default()
            .push_back(data);
        cv.notify_all();
    }

    /// The next message from `from`; panics when `from` has ended without sending it (it
    /// failed: under MPI the job would be aborted), rather than waiting for ever.
    fn receive(&self, from: usize) -> Vec<f64> {
        let (lock, cv) = &*self.shared;
        let mut g = lock.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if let Some(m) = g
                .queues
                .get_mut(&(from, self.rank))
                .and_then(|q| q.pop_front())
            {
                return m;
            }
            assert!(
                !g.ended.contains(&from),
                "rank {}: rank {from} ended without sending the message waited for",
                self.rank
            );
            g = cv.wait(g).unwrap_or_else(|e| e.into_inner());
        }
    }
}

impl Comm for ThreadComm {
    fn rank(&self) -> usize {
        self.rank
    }
    fn size(&self) -> usize {
        self.size
    }
    fn all_gather(&self, local: &[f64]) -> Vec<Vec<f64>> {
        for q in (0..self.size).filter(|&q| q != self.rank) {
            self.send(q, local.to_vec());
        }
        (0..self.size)
            .map(|q| {
                if q == self.rank {
                    local.to_vec()
                } else {
                    self.receive(q)
                }
            })
            .collect()
    }
    fn exchange(&self, sends: &[(usize, Vec<f64>)], recvs: &mut [(usize, Vec<f64>)]) {
        for (q, data) in sends {
            self.send(*q, data.clone());
        }
        for (q, buf) in recvs.iter_mut() {
            let m = self.receive(*q);
            assert_eq!(m.len(), buf.len(), "message length from rank {q}");
            buf.copy_from_slice(&m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rank_that_fails_does_not_leave_the_others_waiting() {
        let r = std::panic::catch_unwind(|| {
            ThreadComm::run(3, |c| {
                if c.rank() == 1 {
                    panic!("rank 1 fails before the collective");
                }
                c.sum(&[1.0])
            })
        });
        assert!(r.is_err(), "the failure reaches the caller");
    }

    #[test]
    fn thread_ranks_gather_sum_and_exchange() {
        let out = ThreadComm::run(3, |c| {
            let r = c.rank() as f64;
            let sum = c.sum(&[r, 1.0]);
            let max = c.max(&[r])[0];
            // a ring: send my rank to the next, receive the previous one's
            let next = (c.rank() + 1) % 3;
            let prev = (c.rank() + 2) % 3;
            let mut recvs = vec![(prev, vec![0.0; 1])];
            c.exchange(&[(next, vec![r])], &mut recvs);
            (sum, max, recvs[0].1[0])
        });
        for (rank, (sum, max, got)) in out.into_iter().enumerate() {
            assert_eq!(sum, vec![3.0, 3.0]);
            assert_eq!(max, 2.0);
            assert_eq!(got, ((rank + 2) % 3) as f64);
        }
    }
}
