//! A bench of emulated MIT motors on virtual CAN buses, each turning an [`InertiaPlant`]: the
//! smallest [`SimWorld`] a driver can be tested against. The mirrored simulator does the same with
//! MuJoCo joints as plants.
//!
//! Events run in time order: frames reaching a motor are answered at arrival (the reply then
//! takes its own wire time), and every firmware period each motor runs its PD law and its plant
//! is integrated.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::firmware::{MitFirmwareConfig, MitMotorFirmware};
use crate::can::virtual_bus::{LockstepCanPort, VirtualCanBus, VirtualCanNode};
use crate::plant::InertiaPlant;
use crate::time::SimInstant;
use crate::time::SimWorld;

/// One motor on the rig.
#[derive(Debug)]
pub struct RigMotor {
    /// Which rig bus it is on.
    pub bus: usize,
    node: VirtualCanNode,
    /// Its firmware.
    pub firmware: MitMotorFirmware,
    /// Its load.
    pub plant: InertiaPlant,
}

/// Emulated motors on virtual buses, stepping in simulated time.
#[derive(Debug)]
pub struct MitRig {
    buses: Vec<VirtualCanBus>,
    motors: Vec<RigMotor>,
    now: SimInstant,
    period: Duration,
    next_tick: SimInstant,
}

impl MitRig {
    /// A rig whose firmware runs every `period` (e.g. 500 µs for a 2 kHz loop).
    pub fn new(buses: Vec<VirtualCanBus>, period: Duration) -> Self {
        Self {
            buses,
            motors: Vec::new(),
            now: SimInstant::ZERO,
            period,
            next_tick: SimInstant::ZERO,
        }
    }

    /// Adds a motor on rig bus `bus` driving `plant`. Returns its index.
    ///
    /// # Panics
    /// When `bus` is not a bus of this rig.
    pub fn add_motor(&mut self, bus: usize, cfg: MitFirmwareConfig, plant: InertiaPlant) -> usize {
        let node = self.buses[bus].attach();
        self.motors.push(RigMotor {
            bus,
            node,
            firmware: MitMotorFirmware::new(cfg),
            plant,
        });
        self.motors.len() - 1
    }

    /// The rig's buses.
    pub fn buses(&self) -> &[VirtualCanBus] {
        &self.buses
    }

    /// The motors, in the order added.
    pub fn motors(&self) -> &[RigMotor] {
        &self.motors
    }

    /// A motor, to inspect or inject faults.
    pub fn motor_mut(&mut self, index: usize) -> &mut RigMotor {
        &mut self.motors[index]
    }

    /// Wraps the rig for sharing with host ports.
    pub fn shared(self) -> Arc<Mutex<Self>> {
        Arc::new(Mutex::new(self))
    }

    /// A host adapter on rig bus `bus` that advances the shared rig while it waits.
    pub fn host_port(rig: &Arc<Mutex<Self>>, bus: usize) -> LockstepCanPort<Self> {
        let node = rig
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .buses[bus]
            .attach();
        LockstepCanPort::new(node, Arc::clone(rig))
    }

    fn set_now(&mut self, t: SimInstant) {
        self.now = t;
        for bus in &self.buses {
            bus.set_now(t);
        }
    }
}

impl SimWorld for MitRig {
    fn now(&self) -> SimInstant {
        self.now
    }

    fn step_until(&mut self, limit: SimInstant) -> SimInstant {
        let next_frame = self.motors.iter().filter_map(|m| m.node.next_arrival()).min();
        let t = [Some(self.next_tick), next_frame, Some(limit)]
            .into_iter()
            .flatten()
            .min()
            .unwrap_or(limit);
        let t = t.max(self.now);
        self.set_now(t);
        for m in &mut self.motors {
            while let Some(frame) = m.node.try_recv() {
                if let Some(reply) = m.firmware.on_frame(t, &frame, &m.plant) {
                    // A send refused while bus-off is lost, as on a real bus.
                    let _ = m.node.send(&reply);
                }
            }
        }
        if t >= self.next_tick {
            let dt = self.period.as_secs_f64();
            for m in &mut self.motors {
                m.firmware.tick(t, self.period, &mut m.plant);
                m.plant.integrate(dt);
            }
            self.next_tick = self.next_tick + self.period;
        }
        t
    }
}
