//! A recorded VR session as a sender: headset, controller and foot tracker poses synthesised from
//! a BVH's head, hands and feet (fixed device offsets, sensor noise, the headset's rate), or the whole skeleton's
//! bones as a motion-capture suit sends them, streamed as VMC over UDP, so teleoperation can be
//! tested and shown without a headset or a suit. The session starts with the
//! recording's first frame held as the T-pose the receiver calibrates from.

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::body_map::Frame;
use firmware_bridge::time::SimRng;
use robots::spatial::{self, Mat3};

use super::osc::{self, Arg};
use super::retarget::{bvh_joint, orientation_joint};
use super::vmc::{robot_to_unity_position, robot_to_unity_quat};
use crate::HumanError;
use crate::skeleton::{self, Skeleton};
use motion::bvh::Bvh;
use robots::HumanBody;

/// How the session is sent.
#[derive(Debug, Clone, PartialEq)]
pub struct SendOptions {
    /// Packets per second (VR runtimes: 30–90 Hz).
    pub rate_hz: f64,
    /// Hold the first frame (a T-pose) this long before the motion, s.
    pub tpose_s: f64,
    /// First frame of the motion after the T-pose.
    pub start_frame: usize,
    /// Stop after this many seconds (T-pose included); `None`: at the end of the recording.
    pub seconds: Option<f64>,
    /// Position noise, standard deviation, m.
    pub noise_m: f64,
    /// Orientation noise, standard deviation, rad.
    pub noise_rad: f64,
    /// Noise seed.
    pub seed: u64,
    /// What is sent: a headset and two controllers, or the whole skeleton's bones.
    pub body: BodySet,
    /// Past the recording's end, start its motion again (from `start_frame`).
    pub looped: bool,
}

/// What a sender sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BodySet {
    /// A headset and two controllers (`/VMC/Ext/Hmd/Pos`, `/VMC/Ext/Con/Pos`).
    #[default]
    Devices,
    /// The same and a tracker on each foot (`/VMC/Ext/Tra/Pos`, serials `LeftFoot`, `RightFoot`).
    DevicesAndFeet,
    /// The whole skeleton: the root and the bones (`/VMC/Ext/Root/Pos`, `/VMC/Ext/Bone/Pos`).
    Skeleton,
}

impl Default for SendOptions {
    fn default() -> Self {
        Self {
            rate_hz: 72.0,
            tpose_s: 1.5,
            start_frame: 1,
            seconds: None,
            noise_m: 0.002,
            noise_rad: 0.004,
            seed: 1,
            body: BodySet::Devices,
            looped: false,
        }
    }
}

/// Where the devices sit on the body: the headset 8 cm in front of and 7 cm above the head joint,
/// each controller's grip 9 cm beyond the wrist along the forearm, each foot tracker on the instep
/// 6 cm in front of and 5 cm above the ankle joint. Device axes: x forward, z up in the T-pose,
/// turning with the head, hand or foot after.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    joints: [usize; 5],
    offsets: [[f64; 3]; 5],
    turn: [Mat3; 5],
}

impl Rig {
    /// The device rig of `bvh`, measured on its first frame (a T-pose).
    pub fn new(bvh: &Bvh) -> Result<Self, HumanError> {
        let find = |b: HumanBody| {
            let name = bvh_joint(bvh.dialect, b);
            bvh.joint(name)
                .ok_or_else(|| HumanError::map(format!("the recording has no {name} joint")))
        };
        let joints = [
            find(HumanBody::Head)?,
            find(HumanBody::LeftHand)?,
            find(HumanBody::RightHand)?,
            find(HumanBody::LeftFoot)?,
            find(HumanBody::RightFoot)?,
        ];
        let elbows = [find(HumanBody::LeftElbow)?, find(HumanBody::RightElbow)?];
        let p = bvh.pose(0);
        let lateral = spatial::sub(p.pos[joints[1]], p.pos[joints[2]]);
        let body = spatial::yaw(lateral[1].atan2(lateral[0]) - std::f64::consts::FRAC_PI_2);
        let forward = spatial::mat_apply(&body, [1.0, 0.0, 0.0]);
        let local = |j: usize, v: [f64; 3]| spatial::mat_apply(&spatial::transpose(&p.rot[j]), v);
        let grip = |side: usize| {
            let along = spatial::unit(spatial::sub(p.pos[joints[side + 1]], p.pos[elbows[side]]));
            local(joints[side + 1], spatial::scale(along, 0.09))
        };
        Ok(Self {
            joints,
            offsets: [
                local(
                    joints[0],
                    spatial::add(spatial::scale(forward, 0.08), [0.0, 0.0, 0.07]),
                ),
                grip(0),
                grip(1),
                local(
                    joints[3],
                    spatial::add(spatial::scale(forward, 0.06), [0.0, 0.0, 0.05]),
                ),
                local(
                    joints[4],
                    spatial::add(spatial::scale(forward, 0.06), [0.0, 0.0, 0.05]),
                ),
            ],
            turn: joints.map(|j| spatial::mat_mul(&spatial::transpose(&p.rot[j]), &body)),
        })
    }

    /// Headset, left and right controller, left and right foot tracker at `frame`, robot axes,
    /// without noise.
    pub fn devices(&self, bvh: &Bvh, frame: usize) -> [Frame; 5] {
        self.devices_in(&bvh.pose(frame))
    }

    /// The devices on the recording's pose `p`.
    pub fn devices_in(&self, p: &motion::bvh::Pose) -> [Frame; 5] {
        [0, 1, 2, 3, 4].map(|k| {
            let j = self.joints[k];
            Frame {
                pos: spatial::add(p.pos[j], spatial::mat_apply(&p.rot[j], self.offsets[k])),
                rot: spatial::mat_mul(&p.rot[j], &self.turn[k]),
            }
        })
    }
}

/// The skeleton's bones at a recording's frame: each bone of [`skeleton::BODIES`] at its BVH
/// joint (the toes' bones at the toes), robot axes, without noise.
#[derive(Debug, Clone, PartialEq)]
pub struct SkeletonRig {
    joints: Vec<(usize, usize)>,
}

impl SkeletonRig {
    /// The bones `bvh` has joints for (every body the retargeting map may pair).
    pub fn new(bvh: &Bvh) -> Result<Self, HumanError> {
        let mut joints = Vec::new();
        for (body, bone, toes) in skeleton::BODIES {
            let name = bvh_joint(bvh.dialect, body);
            let j = bvh
                .joint(name)
                .ok_or_else(|| HumanError::map(format!("the recording has no {name} joint")))?;
            joints.push((bone, j));
            if toes != bone
                && let Some(t) = orientation_joint(bvh.dialect, body).and_then(|n| bvh.joint(n))
            {
                joints.push((toes, t));
            }
        }
        Ok(Self { joints })
    }

    /// Each sent bone's world frame at `frame`.
    pub fn bones(&self, bvh: &Bvh, frame: usize) -> [Option<Frame>; 22] {
        let p = bvh.pose(frame);
        let mut out = [None; 22];
        for &(bone, j) in &self.joints {
            out[bone] = Some(Frame {
                pos: p.pos[j],
                rot: p.rot[j],
            });
        }
        out
    }
}

/// The VMC packet (one bundle: the root, then each sent bone local to its parent) for `skeleton`.
pub fn skeleton_packet(skeleton: &Skeleton, out: &mut Vec<u8>) {
    out.clear();
    let mut messages: Vec<Vec<u8>> = Vec::with_capacity(23);
    if let Some(root) = &skeleton.root {
        let mut m = Vec::new();
        pose_message(&mut m, "/VMC/Ext/Root/Pos", "root", root);
        messages.push(m);
    }
    for (b, f) in skeleton.bones.iter().enumerate() {
        if let Some(f) = f {
            let mut m = Vec::new();
            pose_message(&mut m, "/VMC/Ext/Bone/Pos", skeleton::BONES[b], f);
            messages.push(m);
        }
    }
    let refs: Vec<&[u8]> = messages.iter().map(Vec::as_slice).collect();
    osc::encode_bundle(out, &refs);
}

/// Which recording frame is sent at time `t` since the start.
pub fn frame_at(bvh: &Bvh, options: &SendOptions, t: f64) -> Option<usize> {
    if t < options.tpose_s {
        return Some(0);
    }
    let f = ((t - options.tpose_s) / bvh.frame_time).round() as usize;
    let motion = bvh.frames().saturating_sub(options.start_frame).max(1);
    if options.looped {
        return Some(options.start_frame + f % motion);
    }
    (options.start_frame + f < bvh.frames()).then_some(options.start_frame + f)
}

/// One VMC pose message: `address` with `name`, the position and the rotation in Unity's axes.
fn pose_message(out: &mut Vec<u8>, address: &str, name: &str, f: &Frame) {
    let p = robot_to_unity_position(f.pos);
    let q = robot_to_unity_quat(spatial::quat_of_mat(&f.rot));
    let args = [
        Arg::Str(name),
        Arg::Float(p[0] as f32),
        Arg::Float(p[1] as f32),
        Arg::Float(p[2] as f32),
        Arg::Float(q[0] as f32),
        Arg::Float(q[1] as f32),
        Arg::Float(q[2] as f32),
        Arg::Float(q[3] as f32),
    ];
    osc::encode_message(out, address, &args);
}

/// The VMC packet (one bundle) for `devices`: headset, left and right controller, then the left
/// and right foot tracker where given.
pub fn packet(devices: &[Frame], out: &mut Vec<u8>) {
    out.clear();
    let names = [
        ("/VMC/Ext/Hmd/Pos", "HMD"),
        ("/VMC/Ext/Con/Pos", "LeftController"),
        ("/VMC/Ext/Con/Pos", "RightController"),
        ("/VMC/Ext/Tra/Pos", "LeftFoot"),
        ("/VMC/Ext/Tra/Pos", "RightFoot"),
    ];
    let mut messages: [Vec<u8>; 5] = Default::default();
    for ((m, (address, serial)), d) in messages.iter_mut().zip(names).zip(devices) {
        pose_message(m, address, serial, d);
    }
    let n = devices.len().min(names.len());
    let refs: [&[u8]; 5] = [0, 1, 2, 3, 4].map(|k| messages[k].as_slice());
    osc::encode_bundle(out, &refs[..n]);
}

/// Sends the session to `to` in real time until it ends or `stop` is set; `sent` hears the time
/// and recording frame of each packet. Returns the packets sent.
pub fn send(
    bvh: &Bvh,
    to: SocketAddr,
    options: &SendOptions,
    stop: &AtomicBool,
    sent: &mut dyn FnMut(Duration, usize),
) -> Result<u64, HumanError> {
    let worn = match options.body {
        BodySet::Devices => 3,
        _ => 5,
    };
    let (rig, bones) = match options.body {
        BodySet::Devices | BodySet::DevicesAndFeet => (Some(Rig::new(bvh)?), None),
        BodySet::Skeleton => (None, Some(SkeletonRig::new(bvh)?)),
    };
    let local = if to.is_ipv4() {
        SocketAddr::from(([127, 0, 0, 1], 0))
    } else {
        SocketAddr::from((std::net::Ipv6Addr::LOCALHOST, 0))
    };
    let socket = UdpSocket::bind(local).map_err(|e| HumanError::io("cannot open a UDP socket", e))?;
    let mut rng = SimRng::new(options.seed);
    let period = Duration::try_from_secs_f64(1.0 / options.rate_hz)
        .map_err(|_| HumanError::map(format!("{} Hz is not a sending rate", options.rate_hz)))?;
    let start = Instant::now();
    let mut buf = Vec::with_capacity(512);
    let mut count = 0u64;
    for k in 0u32.. {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let t = (period * k).as_secs_f64();
        if options.seconds.is_some_and(|s| t >= s) {
            break;
        }
        let Some(frame) = frame_at(bvh, options, t) else {
            break;
        };
        let mut noisy = |f: &mut Frame| {
            let n = [0; 3].map(|_| options.noise_m * rng.gaussian());
            f.pos = spatial::add(f.pos, n);
            let w = [0; 3].map(|_| options.noise_rad * rng.gaussian());
            f.rot = spatial::mat_mul(&spatial::exp(w), &f.rot);
        };
        if let Some(rig) = &rig {
            let mut devices = rig.devices(bvh, frame);
            devices.iter_mut().for_each(&mut noisy);
            packet(&devices[..worn], &mut buf);
        }
        if let Some(bones) = &bones {
            let mut world = bones.bones(bvh, frame);
            world.iter_mut().flatten().for_each(&mut noisy);
            skeleton_packet(&Skeleton::from_world(&world), &mut buf);
        }
        if let Some(wait) = (start + period * k).checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        socket
            .send_to(&buf, to)
            .map_err(|e| HumanError::io(format!("cannot send to {to}"), e))?;
        sent(start.elapsed(), frame);
        count += 1;
    }
    Ok(count)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_t_pose_is_held_then_the_motion_plays_and_loops_only_when_asked() {
        let bvh = Bvh::load(
            &test_support::fixtures::workspace_root().join("data/mocap/cmu_13_26_direct-traffic-wave.bvh"),
        )
        .unwrap();
        let options = SendOptions::default();
        let dt = bvh.frame_time;
        assert_eq!(frame_at(&bvh, &options, 0.5), Some(0));
        assert_eq!(frame_at(&bvh, &options, options.tpose_s + 10.0 * dt), Some(11));
        let past = options.tpose_s + bvh.frames() as f64 * dt;
        assert_eq!(frame_at(&bvh, &options, past), None);
        let looped = SendOptions {
            looped: true,
            ..options.clone()
        };
        // Past the end the motion starts again at start_frame (the T-pose frame is not replayed).
        let motion = (bvh.frames() - options.start_frame) as f64;
        assert_eq!(
            frame_at(&bvh, &looped, options.tpose_s + (motion + 3.0) * dt),
            Some(4)
        );
    }
}
