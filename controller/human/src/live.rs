//! Live references from another thread (teleoperation, a motion generator) into the control
//! loop, lock-free; and the forecast that carries a late stream forward.
//!
//! One writer (the worker thread) and one reader (the control tick) share three preallocated
//! frames that circulate through two bounded lock-free queues: the writer fills its own frame and
//! swaps it in as the newest (taking back an unread one), the reader swaps the newest for the one it
//! held. Neither side ever waits for the other, nothing is allocated after [`live_channel`], and
//! the reader always sees a whole frame (never half of one write and half of the next).

use std::sync::Arc;
use std::time::Instant;

use crossbeam::queue::ArrayQueue;

pub use policy::TRACKER_VALUES;

/// A reference computed live by another thread: the frame to track now, robot joint order, and
/// when the input it came from arrived.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveFrame {
    /// Joint positions, rad.
    pub q: Vec<f64>,
    /// Joint velocities, rad/s.
    pub qd: Vec<f64>,
    /// Root pose `[x, y, z, w, qx, qy, qz]`.
    pub root: [f64; 7],
    /// Root velocity, world frame, m/s.
    pub root_lin_vel: [f64; 3],
    /// Root angular velocity, world frame, rad/s.
    pub root_ang_vel: [f64; 3],
    /// Arrival of the newest input sample this frame used.
    pub source: Option<Instant>,
    /// The input devices' poses, as the `tracker_poses` observation term wants them.
    pub trackers: [f64; TRACKER_VALUES],
    /// Where the operator's key bodies are, scaled onto the robot, in the frame of `root` (the
    /// reference's `live_bodies`); empty while no operator is followed.
    pub bodies: Vec<[f64; 3]>,
}

impl LiveFrame {
    /// `q` held still at `root`, no input yet.
    pub fn still(q: Vec<f64>, root: [f64; 7]) -> Self {
        Self {
            qd: vec![0.0; q.len()],
            q,
            root,
            root_lin_vel: [0.0; 3],
            root_ang_vel: [0.0; 3],
            source: None,
            trackers: [0.0; TRACKER_VALUES],
            bodies: Vec::new(),
        }
    }
}

#[derive(Debug)]
struct Shared<T> {
    /// The newest published frame, if the reader has not taken it yet.
    newest: ArrayQueue<Box<T>>,
    /// Frames the reader gave back for the writer to fill again.
    spare: ArrayQueue<Box<T>>,
}

/// The writing half: owned by the thread that computes the live reference.
#[derive(Debug)]
pub struct LiveWriter<T = LiveFrame> {
    shared: Arc<Shared<T>>,
    draft: Option<Box<T>>,
    published: u64,
}

/// The reading half: owned by the control loop.
#[derive(Debug)]
pub struct LiveReader<T = LiveFrame> {
    shared: Arc<Shared<T>>,
    current: Box<T>,
}

/// A writer and a reader sharing frames shaped like `initial` (a live frame, a generator's plan);
/// the reader starts on `initial`.
pub fn live_channel<T: Clone>(initial: T) -> (LiveWriter<T>, LiveReader<T>) {
    let shared = Arc::new(Shared {
        newest: ArrayQueue::new(1),
        spare: ArrayQueue::new(2),
    });
    let _ = shared.spare.push(Box::new(initial.clone()));
    let writer = LiveWriter {
        shared: Arc::clone(&shared),
        draft: Some(Box::new(initial.clone())),
        published: 0,
    };
    let reader = LiveReader {
        shared,
        current: Box::new(initial),
    };
    (writer, reader)
}

impl<T> LiveWriter<T> {
    /// Fills the next frame with `fill` (given the frame last written from this writer's buffers,
    /// possibly older) and makes it the newest. Never blocks the reader.
    pub fn publish(&mut self, fill: impl FnOnce(&mut T)) {
        let mut draft = match self.draft.take() {
            Some(d) => d,
            // Three frames circulate: with none in hand, the reader is between taking the newest
            // and giving its old one back, a few instructions away.
            None => loop {
                if let Some(d) = self.shared.spare.pop() {
                    break d;
                }
                std::hint::spin_loop();
            },
        };
        fill(&mut draft);
        // An unread older frame comes back to be filled next time.
        self.draft = self.shared.newest.force_push(draft);
        self.published += 1;
    }

    /// Frames published so far.
    pub fn published(&self) -> u64 {
        self.published
    }
}

impl<T> LiveReader<T> {
    /// The newest whole frame (the one read before, if nothing new was published).
    pub fn latest(&mut self) -> &T {
        if let Some(newest) = self.shared.newest.pop() {
            let old = std::mem::replace(&mut self.current, newest);
            // Capacity 2 holds every frame the reader can give back; a full queue cannot happen.
            let _ = self.shared.spare.push(old);
        }
        &self.current
    }
}

/// The forecast of a late stream (`o_t = o_{t−1} + δo`): `newest` carried on by the mean velocity
/// between `older` and it (`span` s apart) for `age` s past it, capped at `max` s, into `out`.
/// Teleoperation forecasts tracker positions with it, the motion generator's reference its joints.
pub fn carry_forward(newest: &[f64], older: &[f64], span: f64, age: f64, max: f64, out: &mut [f64]) {
    let ahead = age.clamp(0.0, max);
    for ((o, &n), &b) in out.iter_mut().zip(newest).zip(older) {
        let velocity = if span > 1e-4 { (n - b) / span } else { 0.0 };
        *o = n + velocity * ahead;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reader_sees_the_newest_whole_frame() {
        let (mut w, mut r) = live_channel(LiveFrame::still(vec![0.0; 4], [0.0; 7]));
        assert_eq!(r.latest().q, vec![0.0; 4]);
        for k in 1..=5 {
            w.publish(|f| f.q.fill(f64::from(k)));
        }
        assert_eq!(r.latest().q, vec![5.0; 4]);
        assert_eq!(r.latest().q, vec![5.0; 4], "no new frame: the last one again");
        w.publish(|f| f.q.fill(6.0));
        assert_eq!(r.latest().q, vec![6.0; 4]);
        assert_eq!(w.published(), 6);
    }

    #[test]
    fn frames_stay_whole_under_a_concurrent_writer() {
        let (mut w, mut r) = live_channel(LiveFrame::still(vec![0.0; 64], [0.0; 7]));
        let writer = std::thread::Builder::new()
            .name("live-writer".into())
            .spawn(move || {
                for k in 0..20_000u32 {
                    w.publish(|f| f.q.fill(f64::from(k)));
                }
            })
            .unwrap();
        let mut last = 0.0;
        while !writer.is_finished() {
            let f = r.latest();
            let first = f.q[0];
            assert!(f.q.iter().all(|&v| v == first), "torn frame");
            assert!(first >= last, "frames went back in time");
            last = first;
        }
        writer.join().unwrap();
        assert_eq!(r.latest().q[0], 19_999.0);
    }

    #[test]
    fn a_forecast_carries_on_at_the_recent_velocity_up_to_its_cap() {
        let mut out = [0.0; 2];
        // 1 rad/s and −2 rad/s over the last 0.1 s; 0.05 s late.
        carry_forward(&[1.0, 0.0], &[0.9, 0.2], 0.1, 0.05, 0.2, &mut out);
        assert!(
            (out[0] - 1.05).abs() < 1e-12 && (out[1] + 0.1).abs() < 1e-12,
            "{out:?}"
        );
        // Far too late: capped at 0.2 s of motion.
        carry_forward(&[1.0, 0.0], &[0.9, 0.2], 0.1, 3.0, 0.2, &mut out);
        assert!(
            (out[0] - 1.2).abs() < 1e-12 && (out[1] + 0.4).abs() < 1e-12,
            "{out:?}"
        );
    }
}
