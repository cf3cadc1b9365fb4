//! VMC (Virtual Motion Capture protocol, OSC over UDP) tracker input: the headset, the two
//! controllers and two foot trackers, and a whole body's bones and root where the sender sends them, converted from the sender's Unity axes (left handed, Y up, Z forward) to the
//! robot's (right handed, Z up, X forward), kept per device with their arrival times. The receiver
//! binds to 127.0.0.1 unless told otherwise, ignores addresses it does not use (as VMC asks), and
//! drops and counts malformed, oversized and out-of-range packets without touching its state.

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use crate::body_map::Frame;
use robots::spatial;

use super::osc::{self, Arg};
use crate::skeleton::{self, Skeleton};

/// VMC's default port.
pub const VMC_PORT: u16 = 39539;

/// Largest datagram accepted, bytes (a VMC bundle of a whole skeleton's bones is about 1.5 kB).
pub const MAX_PACKET: usize = 8192;

/// The tracked devices: what a VR operator wears.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Device {
    /// Head-mounted display.
    Headset = 0,
    /// Left hand controller.
    Left = 1,
    /// Right hand controller.
    Right = 2,
    /// A tracker on the left foot (VMC `/VMC/Ext/Tra/Pos`).
    LeftFoot = 3,
    /// A tracker on the right foot.
    RightFoot = 4,
}

impl Device {
    /// The headset and the controllers, in index order.
    pub const HEAD_AND_HANDS: [Device; 3] = [Device::Headset, Device::Left, Device::Right];
    /// The device's name for messages.
    pub fn name(self) -> &'static str {
        match self {
            Self::Headset => "the headset",
            Self::Left => "the left controller",
            Self::Right => "the right controller",
            Self::LeftFoot => "the left foot tracker",
            Self::RightFoot => "the right foot tracker",
        }
    }

    /// Every device, in index order.
    pub const ALL: [Device; 5] = [
        Device::Headset,
        Device::Left,
        Device::Right,
        Device::LeftFoot,
        Device::RightFoot,
    ];
}

/// A Unity position (left handed, Y up, Z forward, X right) in robot axes (X forward, Y left, Z up).
pub fn unity_to_robot_position(p: [f64; 3]) -> [f64; 3] {
    [p[2], -p[0], p[1]]
}

/// A Unity rotation `(x, y, z, w)` as a robot-axes quaternion `[w, x, y, z]`. The change of axes
/// has determinant −1, so the rotation axis (a pseudo-vector) flips: `(w, −z, x, −y)`.
pub fn unity_to_robot_quat(q: [f64; 4]) -> [f64; 4] {
    let [x, y, z, w] = q;
    [w, -z, x, -y]
}

/// The inverse of [`unity_to_robot_position`].
pub fn robot_to_unity_position(p: [f64; 3]) -> [f64; 3] {
    [-p[1], p[2], p[0]]
}

/// The inverse of [`unity_to_robot_quat`]: `[w, x, y, z]` robot to Unity `(x, y, z, w)`.
pub fn robot_to_unity_quat(q: [f64; 4]) -> [f64; 4] {
    let [w, x, y, z] = q;
    [y, -z, -x, w]
}

/// Which controller serial is which hand, and which tracker serial which foot.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Serials {
    /// The left controller's serial (default: any serial containing "left").
    pub left: Option<String>,
    /// The right controller's serial (default: any serial containing "right").
    pub right: Option<String>,
    /// The left foot tracker's serial (default: any tracker serial containing "left").
    pub left_foot: Option<String>,
    /// The right foot tracker's serial (default: any tracker serial containing "right").
    pub right_foot: Option<String>,
}

impl Serials {
    /// The device a serial names: `sides` are the left and right ones of its kind (controllers
    /// or trackers), with their serials where given.
    fn side(serial: &str, wanted: [&Option<String>; 2], sides: [Device; 2]) -> Option<Device> {
        let is = |want: &Option<String>, word: &str| match want {
            Some(s) => s == serial,
            None => serial.to_ascii_lowercase().contains(word),
        };
        if is(wanted[0], "left") {
            Some(sides[0])
        } else if is(wanted[1], "right") {
            Some(sides[1])
        } else {
            None
        }
    }

    fn hand(&self, serial: &str) -> Option<Device> {
        Self::side(serial, [&self.left, &self.right], [Device::Left, Device::Right])
    }

    fn foot(&self, serial: &str) -> Option<Device> {
        Self::side(
            serial,
            [&self.left_foot, &self.right_foot],
            [Device::LeftFoot, Device::RightFoot],
        )
    }
}

/// What the receiver has seen, counted.
#[derive(Debug, Default)]
pub struct Counters {
    /// Datagrams received.
    pub packets: AtomicU64,
    /// Device poses accepted.
    pub poses: AtomicU64,
    /// Datagrams that were not well-formed OSC, or a known address with wrong arguments.
    pub malformed: AtomicU64,
    /// Datagrams larger than [`MAX_PACKET`].
    pub oversized: AtomicU64,
    /// Poses with non-finite values, positions beyond 20 m or quaternions far from unit length.
    pub out_of_range: AtomicU64,
    /// Messages for addresses this receiver does not use (ignored, as VMC asks).
    pub ignored: AtomicU64,
}

impl Counters {
    /// `(packets, poses, malformed, oversized, out_of_range, ignored)`.
    pub fn snapshot(&self) -> [u64; 6] {
        [
            &self.packets,
            &self.poses,
            &self.malformed,
            &self.oversized,
            &self.out_of_range,
            &self.ignored,
        ]
        .map(|c| c.load(Ordering::Relaxed))
    }
}

/// Samples kept per device.
pub const HISTORY: usize = 8;

/// One device's recent poses (robot axes), newest last.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Track {
    /// Arrival time and pose of the kept samples.
    pub samples: [Option<(Instant, Frame)>; HISTORY],
    /// How many are kept.
    pub len: usize,
}

impl Default for Track {
    fn default() -> Self {
        Self {
            samples: [None; HISTORY],
            len: 0,
        }
    }
}

impl Track {
    fn push(&mut self, at: Instant, f: Frame) {
        if self.len == HISTORY {
            self.samples.rotate_left(1);
            self.len -= 1;
        }
        self.samples[self.len] = Some((at, f));
        self.len += 1;
    }

    /// The newest sample.
    pub fn newest(&self) -> Option<(Instant, Frame)> {
        self.len.checked_sub(1).and_then(|i| self.samples[i])
    }
}

/// What every device has sent, shared between the receiver thread and its readers.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Tracks {
    /// Per device (see [`Device`]).
    pub devices: [Track; 5],
    /// The whole body, where the sender sends bones (each bone's newest pose).
    pub skeleton: Skeleton,
    /// Arrival of the newest bone or root pose.
    pub skeleton_at: Option<Instant>,
}

/// Decodes one datagram into `tracks`: returns how many poses it accepted. Nothing of a packet is
/// applied unless all of it is well formed and in range.
pub fn decode(
    packet: &[u8],
    serials: &Serials,
    at: Instant,
    tracks: &mut Tracks,
    counters: &Counters,
) -> usize {
    counters.packets.fetch_add(1, Ordering::Relaxed);
    let mut poses: [Option<(Target, Frame)>; 32] = [None; 32];
    let mut n = 0;
    let mut bad_args = false;
    let mut out_of_range = false;
    let mut ignored = 0;
    let parsed = osc::parse(packet, &mut |m| {
        // Poses: a name and a position and rotation (a root may add its scale and offset, VMC 2.1).
        let (kind, most) = match m.address {
            "/VMC/Ext/Hmd/Pos" => (Kind::Headset, 7),
            "/VMC/Ext/Con/Pos" => (Kind::Controller, 7),
            "/VMC/Ext/Tra/Pos" => (Kind::Tracker, 7),
            "/VMC/Ext/Bone/Pos" => (Kind::Bone, 7),
            "/VMC/Ext/Root/Pos" => (Kind::Root, 13),
            _ => {
                ignored += 1;
                return;
            }
        };
        let mut args = m.args();
        let (Some(Ok(Arg::Str(name))), values) = (args.next(), args) else {
            bad_args = true;
            return;
        };
        let mut v = [0.0f64; 13];
        let mut count = 0;
        for a in values {
            match a {
                Ok(Arg::Float(x)) if count < most => v[count] = f64::from(x),
                _ => {
                    bad_args = true;
                    return;
                }
            }
            count += 1;
        }
        if count != 7 && count != most {
            bad_args = true;
            return;
        }
        let target = match kind {
            Kind::Headset => Some(Target::Device(Device::Headset)),
            Kind::Controller => serials.hand(name).map(Target::Device),
            Kind::Tracker => serials.foot(name).map(Target::Device),
            Kind::Bone => skeleton::bone_index(name).map(Target::Bone),
            Kind::Root => Some(Target::Root),
        };
        let Some(target) = target else {
            ignored += 1;
            return;
        };
        let qn = (v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]).sqrt();
        if v.iter().any(|x| !x.is_finite())
            || v[..3].iter().any(|x| x.abs() > 20.0)
            || !(0.9..=1.1).contains(&qn)
        {
            out_of_range = true;
            return;
        }
        let q = unity_to_robot_quat([v[3] / qn, v[4] / qn, v[5] / qn, v[6] / qn]);
        if n < poses.len() {
            poses[n] = Some((
                target,
                Frame {
                    pos: unity_to_robot_position([v[0], v[1], v[2]]),
                    rot: spatial::mat_of_quat(q),
                },
            ));
            n += 1;
        }
    });
    counters.ignored.fetch_add(ignored, Ordering::Relaxed);
    if parsed.is_err() || bad_args {
        counters.malformed.fetch_add(1, Ordering::Relaxed);
        return 0;
    }
    if out_of_range {
        counters.out_of_range.fetch_add(1, Ordering::Relaxed);
        return 0;
    }
    let mut skeleton = false;
    for (target, frame) in poses[..n].iter().flatten() {
        match *target {
            Target::Device(device) => tracks.devices[device as usize].push(at, *frame),
            Target::Bone(b) => {
                tracks.skeleton.bones[b] = Some(*frame);
                skeleton = true;
            }
            Target::Root => {
                tracks.skeleton.root = Some(*frame);
                skeleton = true;
            }
        }
    }
    if skeleton {
        tracks.skeleton_at = Some(at);
    }
    counters.poses.fetch_add(n as u64, Ordering::Relaxed);
    n
}

/// What a pose message is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Headset,
    Controller,
    Tracker,
    Bone,
    Root,
}

/// Where an accepted pose goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Target {
    Device(Device),
    Bone(usize),
    Root,
}

/// A VMC receiver on its own thread.
#[derive(Debug)]
pub struct VmcReceiver {
    /// Latest tracks.
    pub tracks: Arc<Mutex<Tracks>>,
    /// What arrived, counted.
    pub counters: Arc<Counters>,
    /// Signalled (non-blocking) after each packet with poses, for whoever computes from them.
    pub arrivals: crossbeam::channel::Receiver<Instant>,
    local: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl VmcReceiver {
    /// Listens on `addr` (use 127.0.0.1 unless the sender is elsewhere; port 0 picks one).
    pub fn start(addr: SocketAddr, serials: Serials) -> std::io::Result<Self> {
        let socket = UdpSocket::bind(addr)?;
        socket.set_read_timeout(Some(Duration::from_millis(50)))?;
        let local = socket.local_addr()?;
        let tracks = Arc::new(Mutex::new(Tracks::default()));
        let counters = Arc::new(Counters::default());
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, arrivals) = crossbeam::channel::bounded(1);
        let (t, c, s) = (Arc::clone(&tracks), Arc::clone(&counters), Arc::clone(&stop));
        let thread = std::thread::Builder::new()
            .name("vmc-receiver".into())
            .spawn(move || {
                let mut buf = vec![0u8; MAX_PACKET + 1];
                while !s.load(Ordering::Relaxed) {
                    let Ok(n) = socket.recv(&mut buf) else { continue };
                    let at = Instant::now();
                    if n > MAX_PACKET {
                        c.packets.fetch_add(1, Ordering::Relaxed);
                        c.oversized.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    let mut scratch = *t.lock().unwrap_or_else(PoisonError::into_inner);
                    if decode(&buf[..n], &serials, at, &mut scratch, &c) > 0 {
                        *t.lock().unwrap_or_else(PoisonError::into_inner) = scratch;
                        let _ = tx.try_send(at);
                    }
                }
            })?;
        Ok(Self {
            tracks,
            counters,
            arrivals,
            local,
            stop,
            thread: Some(thread),
        })
    }

    /// Where it listens.
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }
}

impl Drop for VmcReceiver {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// How a device's pose at a given time was obtained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Estimate {
    /// From a sample no older than the sender's period allows.
    Live(Frame),
    /// The sample is late: carried forward by the recent mean velocity (`o_t = o_{t−1} + δo`).
    Forecast(Frame),
    /// Nothing recent enough.
    Missing,
}

/// Resampling and forecasting of a track at the control rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Resampler {
    /// A sample older than this is late, s.
    pub late_after: f64,
    /// Forecast at most this far past the newest sample, s.
    pub forecast_max: f64,
    /// Older than this, the device is missing, s.
    pub lost_after: f64,
}

impl Default for Resampler {
    fn default() -> Self {
        Self {
            late_after: 0.05,
            forecast_max: 0.2,
            lost_after: 0.5,
        }
    }
}

impl Resampler {
    /// The pose of `track` at `now`: the newest sample moved on by the mean velocity of the recent
    /// ones for the time since it arrived (resampling any sender rate to the control rate), capped
    /// at `forecast_max`; the rotation is held.
    pub fn at(&self, track: &Track, now: Instant) -> Estimate {
        let Some((t_last, last)) = track.newest() else {
            return Estimate::Missing;
        };
        let age = now.saturating_duration_since(t_last).as_secs_f64();
        if age > self.lost_after {
            return Estimate::Missing;
        }
        let (mut older, mut span) = (last.pos, 0.0);
        if track.len >= 2 {
            let first = track.len.saturating_sub(4);
            if let (Some((ta, a)), Some((tb, _))) = (track.samples[first], track.samples[track.len - 1]) {
                (older, span) = (a.pos, tb.saturating_duration_since(ta).as_secs_f64());
            }
        }
        let mut pos = [0.0; 3];
        crate::live::carry_forward(&last.pos, &older, span, age, self.forecast_max, &mut pos);
        let frame = Frame { pos, rot: last.rot };
        if age > self.late_after {
            Estimate::Forecast(frame)
        } else {
            Estimate::Live(frame)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vmc(address: &str, serial: &str, v: [f32; 7]) -> Vec<u8> {
        let mut out = Vec::new();
        let args: Vec<Arg<'_>> = std::iter::once(Arg::Str(serial))
            .chain(v.iter().map(|&x| Arg::Float(x)))
            .collect();
        osc::encode_message(&mut out, address, &args);
        out
    }

    #[test]
    fn unity_axes_become_robot_axes() {
        // Unity: 1 m forward (+Z), 0.5 m right (+X), 1.6 m up (+Y) → robot x 1, y −0.5, z 1.6.
        assert_eq!(unity_to_robot_position([0.5, 1.6, 1.0]), [1.0, -0.5, 1.6]);
        // A Unity yaw of +90° about +Y turns forward (+Z) towards the right (+X): in robot axes a
        // turn to the right is −90° about +Z.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let r = spatial::mat_of_quat(unity_to_robot_quat([0.0, h, 0.0, h]));
        let forward = spatial::mat_apply(&r, [1.0, 0.0, 0.0]);
        assert!(
            spatial::norm(spatial::sub(forward, [0.0, -1.0, 0.0])) < 1e-12,
            "{forward:?}"
        );
        // Unity pitch +90° about +X turns forward (+Z) down (−Y): robot nose down is +90° about +Y.
        let r = spatial::mat_of_quat(unity_to_robot_quat([h, 0.0, 0.0, h]));
        let forward = spatial::mat_apply(&r, [1.0, 0.0, 0.0]);
        assert!(
            spatial::norm(spatial::sub(forward, [0.0, 0.0, -1.0])) < 1e-12,
            "{forward:?}"
        );
        // And back.
        let q = [0.3, -0.1, 0.5, 0.8];
        let back = robot_to_unity_quat(unity_to_robot_quat(q));
        assert!(q.iter().zip(back).all(|(a, b)| (a - b).abs() < 1e-15));
        assert_eq!(
            robot_to_unity_position(unity_to_robot_position([1.0, 2.0, 3.0])),
            [1.0, 2.0, 3.0]
        );
    }

    #[test]
    fn poses_land_on_their_devices_and_bad_packets_change_nothing() {
        let c = Counters::default();
        let serials = Serials::default();
        let mut t = Tracks::default();
        let now = Instant::now();
        let hmd = vmc("/VMC/Ext/Hmd/Pos", "HMD", [0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0]);
        let left = vmc(
            "/VMC/Ext/Con/Pos",
            "LeftHand",
            [-0.3, 1.0, 0.2, 0.0, 0.0, 0.0, 1.0],
        );
        let foot = vmc(
            "/VMC/Ext/Tra/Pos",
            "RightFoot",
            [0.1, 0.08, 0.0, 0.0, 0.0, 0.0, 1.0],
        );
        let mut bundle = Vec::new();
        osc::encode_bundle(&mut bundle, &[&hmd, &left, &foot]);
        assert_eq!(decode(&bundle, &serials, now, &mut t, &c), 3);
        assert!((t.devices[Device::RightFoot as usize].newest().unwrap().1.pos[1] + 0.1).abs() < 1e-6);
        assert!(t.devices[Device::LeftFoot as usize].newest().is_none());
        assert_eq!(
            t.devices[0].newest().unwrap().1.pos,
            [0.0, 0.0, 1.600000023841858]
        );
        assert!((t.devices[1].newest().unwrap().1.pos[1] - 0.3).abs() < 1e-6);
        let before = t;
        // Garbage, a truncated bundle, wrong arguments, out of range: counted, nothing applied.
        assert_eq!(decode(b"\x00\x01garbage", &serials, now, &mut t, &c), 0);
        assert_eq!(decode(&bundle[..bundle.len() - 3], &serials, now, &mut t, &c), 0);
        let mut short = Vec::new();
        osc::encode_message(
            &mut short,
            "/VMC/Ext/Hmd/Pos",
            &[Arg::Str("HMD"), Arg::Float(1.0)],
        );
        assert_eq!(decode(&short, &serials, now, &mut t, &c), 0);
        let far = vmc("/VMC/Ext/Hmd/Pos", "HMD", [0.0, 1.6, 500.0, 0.0, 0.0, 0.0, 1.0]);
        let nan = vmc(
            "/VMC/Ext/Hmd/Pos",
            "HMD",
            [0.0, f32::NAN, 0.0, 0.0, 0.0, 0.0, 1.0],
        );
        let unnormal = vmc("/VMC/Ext/Hmd/Pos", "HMD", [0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 3.0]);
        for p in [&far, &nan, &unnormal] {
            assert_eq!(decode(p, &serials, now, &mut t, &c), 0);
        }
        assert_eq!(t, before);
        // Addresses it does not use are ignored, as are controllers that are neither hand and
        // bones outside the humanoid's.
        let blend = vmc("/VMC/Ext/Blend/Val", "Joy", [0.0; 7]);
        assert_eq!(decode(&blend, &serials, now, &mut t, &c), 0);
        let bone = vmc("/VMC/Ext/Bone/Pos", "Tail", [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        let other = vmc(
            "/VMC/Ext/Con/Pos",
            "LHR-1234",
            [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        );
        assert_eq!(decode(&bone, &serials, now, &mut t, &c), 0);
        assert_eq!(decode(&other, &serials, now, &mut t, &c), 0);
        let named = Serials {
            right: Some("LHR-1234".into()),
            ..Serials::default()
        };
        assert_eq!(decode(&other, &named, now, &mut t, &c), 1);
        // A tracker is a foot only by its own serials: the controller's does not name it.
        let tracker = vmc(
            "/VMC/Ext/Tra/Pos",
            "LHR-1234",
            [0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 1.0],
        );
        assert_eq!(decode(&tracker, &named, now, &mut t, &c), 0);
        let feet = Serials {
            left_foot: Some("LHR-1234".into()),
            ..Serials::default()
        };
        assert_eq!(decode(&tracker, &feet, now, &mut t, &c), 1);
        assert!(t.devices[Device::LeftFoot as usize].newest().is_some());
        // A humanoid bone lands in the skeleton, in robot axes, with its arrival.
        assert_eq!(t.skeleton_at, None);
        let hips = vmc("/VMC/Ext/Bone/Pos", "Hips", [0.1, 0.9, 0.2, 0.0, 0.0, 0.0, 1.0]);
        assert_eq!(decode(&hips, &serials, now, &mut t, &c), 1);
        let p = t.skeleton.bones[0].unwrap().pos;
        assert!(
            (p[0] - 0.2).abs() < 1e-6 && (p[1] + 0.1).abs() < 1e-6 && (p[2] - 0.9).abs() < 1e-6,
            "{p:?}"
        );
        assert_eq!(t.skeleton_at, Some(now));
        let [packets, poses, malformed, _, range, ignored] = c.snapshot();
        assert_eq!((packets, poses, malformed, range, ignored), (14, 6, 3, 3, 4));
    }

    #[test]
    fn late_samples_are_forecast_and_old_ones_are_missing() {
        let start = Instant::now();
        let mut track = Track::default();
        for k in 0..5 {
            let at = start + Duration::from_millis(33 * k);
            let pos = [0.1 * k as f64, 0.0, 1.0];
            track.push(
                at,
                Frame {
                    pos,
                    rot: spatial::IDENTITY,
                },
            );
        }
        let r = Resampler::default();
        let last = start + Duration::from_millis(132);
        // 10 ms after the newest sample: live, carried forward 10 ms at ~3 m/s.
        match r.at(&track, last + Duration::from_millis(10)) {
            Estimate::Live(f) => assert!(
                (f.pos[0] - (0.4 + 0.1 / 0.033 * 0.010)).abs() < 2e-3,
                "{:?}",
                f.pos
            ),
            e => panic!("{e:?}"),
        }
        // 100 ms late: forecast; 300 ms: forecast capped at 200 ms; 600 ms: missing.
        assert!(matches!(
            r.at(&track, last + Duration::from_millis(100)),
            Estimate::Forecast(_)
        ));
        let (Estimate::Forecast(a), Estimate::Forecast(b)) = (
            r.at(&track, last + Duration::from_millis(200)),
            r.at(&track, last + Duration::from_millis(300)),
        ) else {
            panic!()
        };
        assert_eq!(a.pos, b.pos);
        assert_eq!(r.at(&track, last + Duration::from_millis(600)), Estimate::Missing);
        assert_eq!(r.at(&Track::default(), last), Estimate::Missing);
    }
}
