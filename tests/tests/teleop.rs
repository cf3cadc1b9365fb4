//! Teleoperation on the mirror: a recorded CMU session streamed as a VR user (VMC over UDP on
//! 127.0.0.1) drives the robot through the T-pose calibration, the retargeting map and live IK;
//! garbage on the same port changes nothing; losing the stream blends back to standby; an
//! independent sender (python-osc) drives it too.

mod common;

use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use controller::clip::Reference;
use controller::player::{EndMode, PlayOptions, PlaySummary, Player};
use human::body_map::Frame;
use human::ik::Ik;
use human::retarget::bvh_joint;
use human::teleop::{Phase, Teleop, TeleopOptions, TeleopStatus, user_frames};
use human::vmc::{Serials, VmcReceiver};
use human::vr_send::{SendOptions, send};
use motion::bvh::Bvh;
use policy::PolicyLayout;
use robot_link::GroundTruth;
use robot_link::TickClock;
use robots::spatial;
use robots::{HumanBody, Robot};
use sim2real::link::PacedLockstepClock;
use sim2real::mirror::Mirror;

/// The paced mirror clock, noting the true joint angles after every tick.
struct Recording {
    inner: PacedLockstepClock,
    world: Arc<Mutex<Mirror>>,
    ticks: Vec<(Instant, Vec<f64>)>,
    status: Arc<Mutex<TeleopStatus>>,
    trackers: Vec<[f64; human::live::TRACKER_VALUES]>,
    /// With `Length::AfterFeed`: when the feed ended, how long to go on, and the stop to raise.
    after_feed: Option<(FeedEnd, Duration, Arc<AtomicBool>)>,
}

/// When the feed ended, once it has.
type FeedEnd = Arc<Mutex<Option<Instant>>>;

/// How long a teleoperated run lasts.
#[derive(Clone, Copy)]
enum Length {
    /// Seconds of ticks.
    Seconds(f64),
    /// Until this long after the feed has ended (a loaded machine may send slower than real time;
    /// what happens after the stream ends must still be seen), within a minute.
    AfterFeed(f64),
}

impl TickClock for Recording {
    fn elapsed(&self) -> Duration {
        self.inner.elapsed()
    }
    fn wait_until(&mut self, deadline: Duration) -> bool {
        let late = self.inner.wait_until(deadline);
        let q = self
            .world
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .joint_positions()
            .collect();
        self.ticks.push((Instant::now(), q));
        self.trackers.push(
            self.status
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .trackers,
        );
        if let Some((ended, after, stop)) = &self.after_feed
            && ended
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .is_some_and(|t| t.elapsed() > *after)
        {
            stop.store(true, Ordering::Relaxed);
        }
        late
    }
    fn ground_truth(&self, truth: &mut GroundTruth) -> bool {
        self.inner.ground_truth(truth)
    }
}

struct Run {
    trackers: Vec<[f64; human::live::TRACKER_VALUES]>,
    summary: PlaySummary,
    status: TeleopStatus,
    counters: [u64; 6],
    ticks: Vec<(Instant, Vec<f64>)>,
    robot: Robot,
}

/// Teleoperates the mirror for `seconds` with the reference follower while `feed` sends to the
/// receiver's address.
fn teleoperate(seconds: f64, options: TeleopOptions, feed: impl FnOnce(SocketAddr) + Send + 'static) -> Run {
    let follower = robots::reference_robot_path().with_file_name("policies/reference_follower.toml");
    teleoperate_with(&follower, Length::Seconds(seconds), options, feed)
}

/// The same with the policy at `policy`.
fn teleoperate_with(
    policy: &std::path::Path,
    length: Length,
    options: TeleopOptions,
    feed: impl FnOnce(SocketAddr) + Send + 'static,
) -> Run {
    let robot = Robot::load(&robots::reference_robot_path()).unwrap();
    let mut layout = PolicyLayout::load(policy, &robot).unwrap();
    let model = policy::onnx::OnnxModel::load(&layout.onnx_path).unwrap();
    layout.bind_model(model.inputs(), model.output().1).unwrap();
    let receiver = VmcReceiver::start("127.0.0.1:0".parse().unwrap(), Serials::default()).unwrap();
    let mut teleop = Teleop::start(&robot, &receiver, options).unwrap();
    let (q, root) = (teleop.standby.clone(), teleop.root);
    let world = Arc::new(Mutex::new(
        Mirror::new(robot.clone(), Default::default()).unwrap(),
    ));
    let io = sim2real::link::lockstep_robot(&robot, &world).unwrap();
    let seconds = match length {
        Length::Seconds(s) => s,
        Length::AfterFeed(_) => 60.0,
    };
    let play = PlayOptions {
        end: EndMode::Loop,
        max_ticks: Some((seconds * 50.0) as u64),
        ..PlayOptions::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let ended: FeedEnd = Arc::default();
    let mut player = Player::new(
        robot.clone(),
        layout,
        Reference::hold(&q, root, 50.0),
        play,
        io,
        Arc::clone(&stop),
    )
    .unwrap()
    .with_source(controller::reference::TeleopStream::new(
        teleop.live.take().unwrap(),
    ));
    let addr = receiver.local_addr();
    let fed = Arc::clone(&ended);
    let feeder = std::thread::Builder::new()
        .name("feed".into())
        .spawn(move || {
            feed(addr);
            *fed.lock().unwrap_or_else(PoisonError::into_inner) = Some(Instant::now());
        })
        .unwrap();
    let mut clock = Recording {
        inner: PacedLockstepClock::new(Arc::clone(&world)),
        world,
        ticks: Vec::new(),
        status: Arc::clone(&teleop.status),
        trackers: Vec::new(),
        after_feed: match length {
            Length::Seconds(_) => None,
            Length::AfterFeed(after) => Some((ended, Duration::from_millis((after * 1e3) as u64), stop)),
        },
    };
    let summary = player.run(&mut clock).unwrap();
    feeder.join().unwrap();
    Run {
        trackers: clock.trackers,
        summary,
        status: teleop.status(),
        counters: receiver.counters.snapshot(),
        ticks: clock.ticks,
        robot,
    }
}

fn mocap() -> Bvh {
    Bvh::load(&test_support::fixtures::workspace_root().join("data/mocap/cmu_13_26_direct-traffic-wave.bvh"))
        .unwrap()
}

/// A feed that runs the python-osc sender (`tests/python/vmc_send.py`) at the address.
fn python_osc(mode: Option<&'static str>) -> impl FnOnce(SocketAddr) + Send + 'static {
    let script = test_support::fixtures::workspace_root().join("tests/python/vmc_send.py");
    let python = test_support::fixtures::venv_python();
    move |addr| {
        let out = std::process::Command::new(python)
            .arg(script)
            .arg(addr.port().to_string())
            .args(mode)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
}

/// The true joint angles of the first tick later than `seconds` into the run.
fn tick_after(run: &Run, seconds: f64) -> &Vec<f64> {
    ticked_after(run, seconds).expect("the run lasted that long")
}

/// [`tick_after`], or none when the run ended before (a starved sender or host began late).
fn ticked_after(run: &Run, seconds: f64) -> Option<&Vec<f64>> {
    let first = run.ticks.first()?.0;
    run.ticks
        .iter()
        .find(|(t, _)| (*t - first).as_secs_f64() > seconds)
        .map(|(_, q)| q)
}

/// How the host starved a real-time run into its overrun stop (the stop a starved loop must
/// make), if it did.
fn overrun_stop(run: &Run) -> Option<String> {
    run.summary
        .transitions
        .iter()
        .find(|t| matches!(t.cause, controller::safety::Cause::Overruns { .. }))
        .map(|t| {
            format!(
                "the host starved the loop into its overrun stop at tick {}",
                t.tick
            )
        })
}

/// Runs `attempt` up to three times while it finds the host starved it (and says how), and
/// returns the first unstarved result; none, said, when every attempt was starved.
fn unstarved<T>(what: &str, mut attempt: impl FnMut() -> Result<T, String>) -> Option<T> {
    for n in 1..=3 {
        match attempt() {
            Ok(t) => return Some(t),
            Err(why) => eprintln!("{what}, attempt {n}: {why}: trying again"),
        }
    }
    eprintln!("skipped: {what}: the host starved it in all 3 attempts");
    None
}

fn joint_index(robot: &Robot, name: &str) -> usize {
    robot.config.joints.iter().position(|j| j.name == name).unwrap()
}

fn at(run: &Run, phase: Phase) -> Option<f64> {
    run.status
        .changes
        .iter()
        .find(|c| c.phase == phase)
        .map(|c| c.at.as_secs_f64())
}

/// Garbage a broken or hostile sender might put on the port.
fn garbage(to: SocketAddr, stop: &AtomicBool) -> usize {
    let s = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut sent = 0;
    let mut good = Vec::new();
    human::osc::encode_message(
        &mut good,
        "/VMC/Ext/Hmd/Pos",
        &[human::osc::Arg::Str("HMD"), human::osc::Arg::Float(f32::NAN)],
    );
    let packets: [&[u8]; 5] = [
        b"\xff\xfe\x00garbage",
        b"#bundle\0\0\0\0\0\0\0\0\x01\0\0\0\x40/x",
        &good,
        &[0u8; 9000],
        b"/VMC/Ext/Hmd/Pos\0\0\0\0,sfffffff\0\0\0",
    ];
    while !stop.load(Ordering::Relaxed) {
        for p in packets {
            s.send_to(p, to).unwrap();
            sent += 1;
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    sent
}

#[test]
fn a_recorded_vr_session_drives_the_robot_and_losing_it_blends_to_standby() {
    let bvh = Arc::new(mocap());
    let follower = robots::reference_robot_path().with_file_name("policies/reference_follower.toml");
    // A session in real time: a sender starved by other work goes silent mid-stream (a loss
    // that did happen), a starved loop falls behind the stream's clock. Both are measured, said,
    // and the session tried again; only an unstarved session decides.
    let attempt = || {
        let sends: Arc<Mutex<Vec<(Instant, usize)>>> = Arc::default();
        let options = SendOptions {
            seconds: Some(8.0),
            ..SendOptions::default()
        };
        let (b, log, o) = (Arc::clone(&bvh), Arc::clone(&sends), options);
        let garbage_sent = Arc::new(Mutex::new(0));
        let g = Arc::clone(&garbage_sent);
        // Lost 0.5 s and standby 1 s after the stream ends: watch 2.5 s past it.
        let run = teleoperate_with(
            &follower,
            Length::AfterFeed(2.5),
            TeleopOptions::default(),
            move |addr| {
                let stop = Arc::new(AtomicBool::new(false));
                let s2 = Arc::clone(&stop);
                let noise = std::thread::Builder::new()
                    .name("garbage".into())
                    .spawn(move || garbage(addr, &s2))
                    .unwrap();
                send(&b, addr, &o, &AtomicBool::new(false), &mut |_, frame| {
                    log.lock().unwrap().push((Instant::now(), frame));
                })
                .unwrap();
                stop.store(true, Ordering::Relaxed);
                *g.lock().unwrap() = noise.join().unwrap();
            },
        );
        let sends = sends.lock().unwrap().clone();
        let gap = sends
            .windows(2)
            .map(|w| (w[1].0 - w[0].0).as_secs_f64())
            .fold(0.0, f64::max);
        if gap > 0.2 {
            return Err(format!("the host starved the sender (silent for {gap:.2} s)"));
        }
        if let Some(why) = overrun_stop(&run) {
            return Err(why);
        }
        let noise = *garbage_sent.lock().unwrap();
        Ok((run, sends, noise))
    };
    let Some((run, sends, noise)) = unstarved("a recorded VR session", attempt) else {
        return;
    };
    let last_send = sends.last().unwrap().0;
    let first_tick = run.ticks[0].0;
    let since = |t: Instant| t.saturating_duration_since(first_tick).as_secs_f64();

    // The T-pose was taken, then tracking, then — after the sender stopped — lost and standby,
    // each within its configured time.
    let tracking = at(&run, Phase::Tracking).expect("tracking started");
    assert!(tracking < 3.0, "{:?}", run.status.changes);
    let lost = at(&run, Phase::Lost).unwrap_or_else(|| {
        panic!(
            "the loss was never noticed: {:?}; {} frames sent until {:.2} s, {} ticks",
            run.status.changes,
            sends.len(),
            since(sends.last().unwrap().0),
            run.ticks.len()
        )
    });
    let standby_at = at(&run, Phase::Standby).expect("standby reached");
    let stop_at = since(last_send);
    assert!(
        lost > stop_at && lost < stop_at + 0.5 + 0.1,
        "lost at {lost:.2} s, sender stopped at {stop_at:.2} s"
    );
    assert!(
        (standby_at - lost - 1.0).abs() < 0.1,
        "standby {standby_at:.2} s after lost {lost:.2} s"
    );
    assert!(!run.summary.fell);

    // Garbage: counted, never a pose, never a loss while the stream ran.
    let [packets, poses, malformed, oversized, range, _] = run.counters;
    assert!(noise > 100);
    assert_eq!(
        poses,
        3 * sends.len() as u64,
        "every good packet and nothing else gave poses"
    );
    assert_eq!(malformed + oversized + range, noise as u64, "{:?}", run.counters);
    assert_eq!(packets, sends.len() as u64 + noise as u64);
    assert_eq!(
        run.status
            .changes
            .iter()
            .filter(|c| c.phase == Phase::Lost)
            .count(),
        1
    );

    // Hand and head errors: the robot's frames (mirror truth, forward kinematics) against the
    // user's true head and wrists through the same calibration and map, with the known pipeline
    // delay shifted out.
    let robot = &run.robot;
    let (user, heading) = run.status.user.unwrap();
    let map = run.status.map.clone().unwrap();
    let origin = run.status.robot_origin;
    let frames = ["head".to_owned(), "left_hand".to_owned(), "right_hand".to_owned()];
    let mut ik = Ik::new(robot, &frames, false, &[]).unwrap();
    let standby: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let root = ik.standing_root(&standby);
    let joints = [HumanBody::Head, HumanBody::LeftHand, HumanBody::RightHand]
        .map(|b| bvh.joint(bvh_joint(bvh.dialect, b)).unwrap());
    let rig = human::vr_send::Rig::new(&bvh).unwrap();
    let zero = human::body_map::UserCalibration {
        head: [0.0; 3],
        left: [0.0; 3],
        right: [0.0; 3],
        ..user
    };
    let target = |frame: usize| {
        // The true joints at the devices' orientations (offsets zero): the error is the pipeline's.
        let p = bvh.pose(frame);
        let d = rig.devices(&bvh, frame);
        let devices = [0, 1, 2].map(|k| {
            Some(Frame {
                pos: p.pos[joints[k]],
                rot: d[k].rot,
            })
        });
        let u = user_frames(&devices, &zero, heading).unwrap();
        [
            map.map(0, &u.head).pos,
            map.map(1, &u.hands[0].unwrap()).pos,
            map.map(2, &u.hands[1].unwrap()).pos,
        ]
    };
    let tracked: Vec<&(Instant, Vec<f64>)> = run
        .ticks
        .iter()
        .filter(|(t, _)| since(*t) > tracking + 1.5 && *t < last_send)
        .collect();
    assert!(tracked.len() > 150);
    let mut errors = |delay: u64| {
        let mut sq = [0.0; 3];
        for (t, q) in &tracked {
            ik.set_pose(root, q);
            let want = *t - Duration::from_millis(delay);
            let frame = sends.iter().rev().find(|(s, _)| *s <= want).map_or(0, |s| s.1);
            let goal = target(frame);
            for k in 0..3 {
                let f = ik.frame(k).pos;
                let robot_pos = [f[0] - origin[0], f[1] - origin[1], f[2]];
                sq[k] += spatial::dot(spatial::sub(robot_pos, goal[k]), spatial::sub(robot_pos, goal[k]));
            }
        }
        sq.map(|s| (s / tracked.len() as f64).sqrt())
    };
    let (delay, best) = (0u64..=15)
        .map(|k| k * 20)
        .map(|d| (d, errors(d)))
        .min_by(|a, b| (a.1[1] + a.1[2]).total_cmp(&(b.1[1] + b.1[2])))
        .unwrap();
    let raw = errors(0);
    // What the robot could reach at all: the same targets solved to convergence (warm started,
    // legs standing), and the robot's distance from that, which is the pipeline's own error.
    let mut best_ik = Ik::new(robot, &frames, false, &(0..12).collect::<Vec<_>>()).unwrap();
    best_ik.set_pose(root, &standby);
    let (mut reach_sq, mut pipe_sq) = ([0.0; 3], [0.0; 3]);
    for (t, q) in &tracked {
        let want = *t - Duration::from_millis(delay);
        let frame = sends.iter().rev().find(|(s, _)| *s <= want).map_or(0, |s| s.1);
        let goal = target(frame);
        let goals = [0, 1, 2].map(|k| human::ik::IkGoal {
            frame: Frame {
                pos: [goal[k][0] + origin[0], goal[k][1] + origin[1], goal[k][2]],
                rot: spatial::IDENTITY,
            },
            position_weight: if k == 0 { 0.0 } else { 1.0 },
            orientation_weight: 0.0,
        });
        best_ik.solve(&goals, 30);
        ik.set_pose(root, q);
        for k in 1..3 {
            let reach = best_ik.frame(k).pos;
            let d = spatial::sub(reach, goals[k].frame.pos);
            reach_sq[k] += spatial::dot(d, d);
            let d = spatial::sub(ik.frame(k).pos, reach);
            pipe_sq[k] += spatial::dot(d, d);
        }
    }
    let n = tracked.len() as f64;
    let reach = reach_sq.map(|s| (s / n).sqrt());
    let pipe = pipe_sq.map(|s| (s / n).sqrt());
    println!(
        "beyond rd-biped's reach: left {:.1} / right {:.1} cm; robot vs its best reachable pose: left {:.1} / right {:.1} cm",
        reach[1] * 100.0,
        reach[2] * 100.0,
        pipe[1] * 100.0,
        pipe[2] * 100.0
    );
    println!(
        "hand RMSE left {:.1} / right {:.1} cm, head {:.1} cm with the pipeline delay {:.0} ms shifted out \
         (unshifted: {:.1} / {:.1} / {:.1} cm); tracker → command latency {}",
        best[1] * 100.0,
        best[2] * 100.0,
        best[0] * 100.0,
        delay,
        raw[1] * 100.0,
        raw[2] * 100.0,
        raw[0] * 100.0,
        run.summary.live_latency.as_ref().unwrap()
    );
    // Bounds: rd-biped's 3-DoF arms cannot reach part of the scaled human's hand positions (that
    // share is measured above); on top of it the servos' tracking at their gains and speed limits
    // may add up to 9 cm. The head moves only by the torso, which stands: within 3 cm.
    for k in 1..3 {
        assert!(
            pipe[k] < 0.09,
            "hand {k}: robot {:.3} m from its best reachable pose",
            pipe[k]
        );
        assert!(
            best[k] < reach[k] + 0.09,
            "hand {k}: {:.3} m off, {:.3} m beyond reach",
            best[k],
            reach[k]
        );
    }
    assert!(best[0] < 0.03, "head {best:?}");
    // The latency of a tracker packet to the first command using it is measured for the inputs
    // the commands used (its bound is the teleop_latency bench's business, not a test's).
    let latency = run.summary.live_latency.as_ref().unwrap();
    assert!(latency.count() > 50, "{latency}");
    // Shortly after standby was reached (the run's own soft stop comes later), the robot is
    // back at the standby pose.
    let last = &run
        .ticks
        .iter()
        .find(|(t, _)| since(*t) > standby_at + 0.3)
        .unwrap()
        .1;
    for (j, (q, s)) in robot.config.joints.iter().zip(last.iter().zip(&standby)) {
        assert!((q - s).abs() < 0.1, "{} at {q:.3}, standby {s:.3}", j.name);
    }
}

#[test]
fn an_independent_sender_python_osc_drives_teleop() {
    // (A 4 s run in real time: a starved sender or host starts tracking too late to judge.)
    let live = unstarved("a python-osc session", || {
        let run = teleoperate(4.0, TeleopOptions::default(), python_osc(None));
        if let Some(why) = overrun_stop(&run) {
            return Err(why);
        }
        let tracking = at(&run, Phase::Tracking).expect("the T-pose was taken");
        match ticked_after(&run, tracking + 2.2) {
            Some(_) => Ok((run, tracking)),
            None => Err(format!("tracking began only {tracking:.2} s into a 4 s run")),
        }
    });
    let Some((run, tracking)) = live else {
        return;
    };
    // Every datagram of the independent sender (about 60 a second) is a pose.
    let [packets, poses, malformed, oversized, range, ignored] = run.counters;
    assert!(packets > 50 && poses == packets, "{:?}", run.counters);
    assert_eq!((malformed, oversized, range, ignored), (0, 0, 0, 0));
    let (user, _) = run.status.user.unwrap();
    assert!((user.stature - 1.70).abs() < 0.05, "stature {}", user.stature);
    // Reaching forward: the right shoulder pitches forward (negative), the left arm stays out.
    let q = tick_after(&run, tracking + 2.2);
    let joint = |name: &str| joint_index(&run.robot, name);
    assert!(
        q[joint("right_shoulder_pitch")] < -0.6,
        "right shoulder pitch {}",
        q[joint("right_shoulder_pitch")]
    );
    assert!(
        q[joint("left_shoulder_roll")] > 1.2,
        "left shoulder roll {}",
        q[joint("left_shoulder_roll")]
    );
}

#[test]
fn the_cli_names_bad_input() {
    let run = |args: &[&str]| {
        let o = test_support::bin::robodeploy().args(args).output().unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let (ok, e) = run(&["vr", "send", "--bvh", "no/such.bvh"]);
    assert!(!ok && e.contains("no/such.bvh"), "{e}");
    let (ok, e) = run(&["teleop", "--listen", "127.0.0.1:0", "--blend=-1"]);
    assert!(
        !ok && e.contains("'--blend <BLEND>': -1 is outside [0, 60]"),
        "{e}"
    );
    let (ok, e) = run(&["vr", "send", "--bvh", "x.bvh", "--to", "not-an-address"]);
    assert!(!ok && e.contains("not-an-address"), "{e}");
}

#[test]
fn a_sparse_input_policy_sees_the_trackers_at_t_and_t_minus_one() {
    let robot = Robot::load(&robots::reference_robot_path()).unwrap();
    let dir = std::env::temp_dir().join(format!("sparse-policy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let names: Vec<String> = robot
        .config
        .joints
        .iter()
        .map(|j| format!("{:?}", j.name))
        .collect();
    let manifest = format!(
        "description = \"untrained MLP with the sparse-input observation (plumbing fixture)\"\n\
         onnx = {:?}\nrate_hz = 50.0\njoints = [{}]\n\
         [action]\nkind = \"position\"\nscale = 0.01\n\
         [[observation]]\nterm = \"tracker_poses\"\nhistory = 2\n\
         [[observation]]\nterm = \"joint_pos\"\nrelative = true\n\
         [[observation]]\nterm = \"joint_vel\"\n\
         [[observation]]\nterm = \"last_actions\"\nk = 1\n",
        test_support::fixtures::fixture("sparse_input_obs114_act20.onnx")
            .display()
            .to_string(),
        names.join(", ")
    );
    let path = dir.join("sparse.toml");
    std::fs::write(&path, manifest).unwrap();
    let layout = PolicyLayout::load(&path, &robot).unwrap();
    assert_eq!(layout.obs_len, 114);

    // The observation stacks the newest tracker poses first, then the previous tick's.
    let mut builder = policy::ObservationBuilder::new(&layout);
    let zeros = vec![0.0; 20];
    let past = vec![0.0f32; 20];
    let still = common::Still {
        q: zeros.clone(),
        height: 0.5,
    };
    let mut obs = vec![0.0f32; 114];
    for k in 0..2 {
        let trackers: [f64; 27] = std::array::from_fn(|i| (10 * k + i) as f64 * 0.01);
        builder.build(
            &policy::ObsInputs {
                trackers: Some(&trackers),
                ..common::at_rest(&zeros, &past, &still)
            },
            &mut obs,
        );
    }
    assert!(
        (obs[0] - 0.10).abs() < 1e-6 && (obs[27] - 0.0).abs() < 1e-6,
        "{:?}",
        &obs[..30]
    );
    assert!((obs[26] - 0.36).abs() < 1e-6 && (obs[53] - 0.26).abs() < 1e-6);

    // Live: python-osc's user drives teleop with this policy; the frame carries the devices in the
    // heading frame at the map's scale (identity rotations: columns x and y).
    // (A 4 s run in real time: a starved sender or host starts tracking too late to judge.)
    let live = unstarved("a sparse-input session", || {
        let run = teleoperate_with(
            &path,
            Length::Seconds(4.0),
            TeleopOptions::default(),
            python_osc(None),
        );
        if let Some(why) = overrun_stop(&run) {
            return Err(why);
        }
        let tracking = at(&run, Phase::Tracking).expect("tracking started");
        match ticked_after(&run, tracking + 1.9) {
            Some(_) => Ok((run, tracking)),
            None => Err(format!("tracking began only {tracking:.2} s into a 4 s run")),
        }
    });
    let Some((run, tracking)) = live else {
        std::fs::remove_dir_all(&dir).unwrap();
        return;
    };
    let scale = run.status.map.as_ref().unwrap().scale;
    // Two seconds into tracking the reach is done.
    let first = run.ticks[0].0;
    let k = run
        .ticks
        .iter()
        .position(|(t, _)| (*t - first).as_secs_f64() > tracking + 1.9)
        .unwrap();
    let t = run.trackers[k];
    assert!((t[2] - scale * 1.59).abs() < 0.02, "headset {:?}", &t[..9]);
    assert!(
        (t[3] - 1.0).abs() < 0.05 && (t[7] - 1.0).abs() < 0.05,
        "headset axes {:?}",
        &t[..9]
    );
    // The right controller ended straight ahead (Unity z 0.55 → robot x), a little right.
    assert!(
        (t[18] - scale * 0.55).abs() < 0.03 && (t[19] + scale * 0.20).abs() < 0.03,
        "right {:?}",
        &t[18..27]
    );
    assert!(run.summary.ticks > 150 && !run.summary.fell);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn headset_only_turns_the_head_and_keeps_the_arms_at_standby() {
    let options = TeleopOptions {
        headset_only: true,
        ..TeleopOptions::default()
    };
    // A 3 s run in real time: a sender or host starved by other work starts tracking late, with
    // too little run left to judge; that is measured, said, and tried again.
    let live = unstarved("a headset-only session", || {
        let run = teleoperate(3.0, options.clone(), python_osc(Some("headset-only")));
        if let Some(why) = overrun_stop(&run) {
            return Err(why);
        }
        let tracking = at(&run, Phase::Tracking).expect("a headset alone calibrates");
        match ticked_after(&run, tracking + 1.6) {
            Some(_) => Ok((run, tracking)),
            None => Err(format!("tracking began only {tracking:.2} s into a 3 s run")),
        }
    });
    let Some((run, tracking)) = live else {
        return;
    };
    let q = tick_after(&run, tracking + 1.6);
    let joint = |name: &str| joint_index(&run.robot, name);
    // The head follows the headset's turn (the policy's speed limit lags it a little).
    let yaw = run
        .ticks
        .iter()
        .map(|(_, q)| q[joint("head_yaw")])
        .fold(f64::MIN, f64::max);
    assert!((yaw - 30f64.to_radians()).abs() < 0.08, "head yaw {yaw}");
    for (k, j) in run
        .robot
        .config
        .joints
        .iter()
        .enumerate()
        .filter(|(_, j)| j.name.contains("shoulder") || j.name.contains("elbow"))
    {
        assert!((q[k] - j.default_position).abs() < 0.1, "{} at {}", j.name, q[k]);
    }
    // Controllers never sent: no hand in the observation either.
    assert!(run.trackers.iter().all(|t| t[9..].iter().all(|v| *v == 0.0)));
}

#[test]
fn a_teleop_session_is_recorded_with_the_files_it_ran_on() {
    let dir = std::env::temp_dir().join(format!("teleop-record-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let record = dir.join("session.mcap");
    let bvh = test_support::fixtures::workspace_root().join("data/mocap/cmu_13_26_direct-traffic-wave.bvh");
    // A 3 s session in real time: a host starved by other work stops the loop on its overruns
    // (exit 3, as it must); that is said and the session tried again. The recording holds its
    // files whatever the end; its length is judged on an unstarved session.
    let session = || {
        let meter = test_support::starvation::StarvationMeter::start();
        let mut teleop = test_support::bin::Running::start(&[
            "teleop",
            "--listen",
            "127.0.0.1:0",
            "--max-seconds",
            "3",
            "--record",
            record.to_str().unwrap(),
            "--overwrite",
        ]);
        let line = teleop.wait_for("listening for VMC on udp://", Duration::from_secs(120));
        let addr = line
            .split("udp://")
            .nth(1)
            .and_then(|s| s.split(';').next())
            .unwrap()
            .to_owned();
        let (ok, _, stderr) = test_support::bin::run(&[
            "vr",
            "send",
            "--bvh",
            bvh.to_str().unwrap(),
            "--to",
            &addr,
            "--seconds",
            "2",
        ]);
        assert!(ok, "{stderr}");
        let done = teleop
            .finish_within(Duration::from_secs(120))
            .expect("the session ends");
        let text = format!("{}{}", done.stdout, done.stderr);
        if done.status.code() == Some(3) && text.contains("deadline overruns in a row") {
            return Err("the host starved the loop into its overrun stop".to_owned());
        }
        // A bus thread starved past its devices' command timeout: the firmware drops torque and
        // the loop damps, as it must; measured, said and tried again.
        let starvation = meter.stop();
        if done.status.code() == Some(3) && text.contains("device fault") && starvation.starved() {
            return Err(format!("a device faulted on a starved host ({starvation})"));
        }
        assert!(done.status.success(), "{starvation}: {text}");
        Ok(())
    };
    let unstarved_session = unstarved("a recorded teleop session", session).is_some();
    let bytes = std::fs::read(&record).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let stats = summary.stats.as_ref().unwrap();
    // 3 s at the policy's 50 Hz, every channel.
    assert!(
        stats.message_count > 150 || !unstarved_session && stats.message_count > 0,
        "{stats:?}"
    );
    let names: Vec<&str> = summary
        .attachment_indexes
        .iter()
        .map(|a| a.name.as_str())
        .collect();
    assert_eq!(
        names,
        [
            "robot/robot.toml",
            "robot/biped.xml",
            "policy/reference_follower.toml"
        ],
        "{names:?}"
    );
    let run = summary.metadata_indexes.iter().find(|m| m.name == "run").unwrap();
    let run = mcap::read::metadata(&bytes, run).unwrap();
    assert!(!run.metadata.contains_key("clip"), "{:?}", run.metadata);
    std::fs::remove_dir_all(&dir).unwrap();
}
