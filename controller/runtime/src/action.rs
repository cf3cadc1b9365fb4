//! The policy's actions as joint commands, per the contract's `[action]`: clip, scale around the
//! default pose (position) or of the joint's torque limit (torque), low-pass, and the governor
//! (position limits with margin, rate limit, torque bounds) before anything reaches a bus.

use robot_link::JointTarget;
use robots::JointConfig;

use crate::safety::{TargetRule, govern_position, govern_torque};
use policy::{ActionKind, PolicyLayout};

/// Turns one tick's actions into targets; remembers past actions for the observation.
#[derive(Debug)]
pub struct ActionMapper {
    /// This tick's actions, policy order (the model writes here).
    actions: Vec<f32>,
    /// The last `k` actions, newest first.
    past: Vec<f32>,
    /// Low-passed position targets, robot order.
    filtered: Vec<f64>,
}

impl ActionMapper {
    /// A mapper for `n` joints remembering `k` past actions, targets starting at `default_q`.
    pub fn new(n: usize, k: usize, default_q: &[f64]) -> Self {
        Self {
            actions: vec![0.0; n],
            past: vec![0.0; k.max(1) * n],
            filtered: default_q.to_vec(),
        }
    }

    /// Starts the low-pass filter from `q` (robot order).
    pub fn reset(&mut self, q: &[f64]) {
        self.filtered.copy_from_slice(q);
    }

    /// The buffer the model writes this tick's actions into.
    pub fn actions_mut(&mut self) -> &mut [f32] {
        &mut self.actions
    }

    /// This tick's actions.
    pub fn actions(&self) -> &[f32] {
        &self.actions
    }

    /// Past actions, newest first.
    pub fn past(&self) -> &[f32] {
        &self.past
    }

    /// Maps this tick's actions into `targets` (robot order) and returns how many joints the
    /// governor limited, and how many of those only into the joint's range (as a trainer's joint
    /// limits bound the same target). `q` is the measured position (robot order).
    pub fn map(
        &mut self,
        layout: &PolicyLayout,
        joints: &[JointConfig],
        q: &[f64],
        targets: &mut [JointTarget],
        dt: f64,
        rule: TargetRule,
    ) -> Governed {
        // Remember actions, newest first.
        let n = self.actions.len();
        let kept = self.past.len() - n;
        self.past.copy_within(..kept, n);
        self.past[..n].copy_from_slice(&self.actions);
        let spec = &layout.manifest.action;
        let alpha = spec.lowpass_hz.map_or(1.0, |fc| {
            let rc = 1.0 / (std::f64::consts::TAU * fc);
            dt / (rc + dt)
        });
        let mut governed = Governed::default();
        for (p, &r) in layout.robot_index.iter().enumerate() {
            let j = &joints[r];
            let a = f64::from(self.actions[p]);
            let a = spec.clip.map_or(a, |c| a.clamp(-c, c));
            targets[r] = match spec.kind {
                ActionKind::Position => {
                    let wanted = layout.default_q[r] + layout.action_scale[r] * a;
                    self.filtered[r] += alpha * (wanted - self.filtered[r]);
                    let previous = targets[r].q;
                    let range = rule.range(j, layout.kp[r]);
                    let sent = govern_position(j, previous, self.filtered[r], dt, range, spec.rate_limit);
                    if sent != self.filtered[r] {
                        governed.limited += 1;
                        if sent == self.filtered[r].clamp(range[0], range[1]) {
                            governed.into_range += 1;
                        }
                    }
                    JointTarget {
                        q: sent,
                        qd: 0.0,
                        kp: layout.kp[r],
                        kd: layout.kd[r],
                        tau: 0.0,
                        enabled: true,
                    }
                }
                ActionKind::Torque => {
                    let wanted = a * j.torque_limit;
                    let tau = govern_torque(j, wanted);
                    if tau != wanted {
                        governed.limited += 1;
                    }
                    JointTarget {
                        q: q[r],
                        qd: 0.0,
                        kp: 0.0,
                        kd: 0.0,
                        tau,
                        enabled: true,
                    }
                }
            };
        }
        governed
    }
}

/// What the governor did to one tick's commands.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Governed {
    /// Joints whose command it changed.
    pub limited: u64,
    /// Of those, joints whose position target it only brought into the joint's range: a target
    /// beyond the joint's range ends at the limit in the trainer's simulation too.
    pub into_range: u64,
}
