//! The host's end of an emulated board in lockstep: a command reaches the board at the world's
//! present, the newest state is the one the board last published, and waiting steps the world.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use crate::time::SimWorld;

use super::board::UnitreeBoard;
use super::host::LowLevelPort;

/// A simulated world with Unitree boards in it (the mirror).
pub trait UnitreeWorld: SimWorld {
    /// Board number `line`.
    fn board_mut(&mut self, line: usize) -> &mut UnitreeBoard;
}

/// The port of board `line` of a shared world.
#[derive(Debug)]
pub struct LockstepUnitreePort<W> {
    world: Arc<Mutex<W>>,
    line: usize,
    /// The sequence number of the newest state taken.
    seen: u64,
}

impl<W: UnitreeWorld> LockstepUnitreePort<W> {
    /// The port of board `line` of `world`.
    pub fn new(world: Arc<Mutex<W>>, line: usize) -> Self {
        Self { world, line, seen: 0 }
    }
}

fn lock<W>(world: &Mutex<W>) -> MutexGuard<'_, W> {
    world.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl<W: UnitreeWorld + Send + std::fmt::Debug> LowLevelPort for LockstepUnitreePort<W> {
    fn send(&mut self, cdr: &[u8]) -> std::io::Result<()> {
        let line = self.line;
        let mut w = lock(&self.world);
        let now = w.now();
        w.board_mut(line).receive(now, cdr);
        Ok(())
    }

    fn newest_state(&mut self, out: &mut Vec<u8>) -> std::io::Result<bool> {
        let line = self.line;
        let mut w = lock(&self.world);
        let (cdr, sequence) = w.board_mut(line).state_cdr();
        if sequence == self.seen {
            return Ok(false);
        }
        self.seen = sequence;
        out.clear();
        out.extend_from_slice(cdr);
        Ok(true)
    }

    fn wait_state(&mut self, within: Duration) -> std::io::Result<bool> {
        let line = self.line;
        let mut w = lock(&self.world);
        let deadline = w.now() + within;
        while w.now() < deadline {
            if w.board_mut(line).state_cdr().1 != self.seen {
                return Ok(true);
            }
            let next = w.board_mut(line).next_state().min(deadline).max(w.now());
            w.step_until(next);
        }
        Ok(w.board_mut(line).state_cdr().1 != self.seen)
    }

    fn state_age(&mut self) -> Option<Duration> {
        let line = self.line;
        let mut w = lock(&self.world);
        let now = w.now();
        w.board_mut(line)
            .published_at()
            .map(|at| now.saturating_since(at))
    }
}
