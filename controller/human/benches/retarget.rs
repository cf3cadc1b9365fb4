//! Bench: retargeting per frame (GMR's two inverse-kinematics stages on the robot's MuJoCo
//! model, planted feet held), on rd-biped and on TWIST2's G1 (when `../shared` is beside the
//! checkout), for every human clip at hand. Target: ≤ 1 ms per frame in a release build, so a
//! live operator at 50 Hz costs a twentieth of a core. Also prints what the frames are worth:
//! planted feet's sliding and the key bodies' distance from the scaled human.
//!
//! Run: `cargo bench -p human --bench retarget`.

use human::retarget::{Nominal, RetargetOptions, retarget_calibrated};
use motion::bvh::Bvh;
use robots::Robot;

fn main() {
    let root = test_support::fixtures::workspace_root();
    let shipped = root.join("data/mocap");
    let mut cases: Vec<(
        std::path::PathBuf,
        std::path::PathBuf,
        Option<std::path::PathBuf>,
        RetargetOptions,
    )> = vec![(
        robots::reference_robot_path(),
        shipped.join("cmu_13_26_direct-traffic-wave.bvh"),
        None,
        RetargetOptions {
            start_frame: 1,
            ..RetargetOptions::default()
        },
    )];
    if let (Some(_), Some(mocap)) = (
        test_support::fixtures::twist2_dir(),
        test_support::fixtures::shared_mocap_dir(),
    ) {
        let g1 = root.join("robots/g1-twist2/robot.toml");
        let standing = RetargetOptions {
            nominal: Nominal::Default,
            ..RetargetOptions::default()
        };
        let wave = mocap.join("bandai2_wave-right-hand_normal_018.bvh");
        let traffic = mocap.join("cmu_13_26_direct-traffic-wave.bvh");
        for (clip, calibration, options) in [
            (
                "bandai2_walk_normal_020.bvh",
                Some(wave.clone()),
                standing.clone(),
            ),
            (
                "bandai2_walk-turn-left_normal_007.bvh",
                Some(wave.clone()),
                standing.clone(),
            ),
            ("bandai2_wave-right-hand_normal_018.bvh", None, standing.clone()),
            (
                "cmu_13_26_direct-traffic-wave.bvh",
                None,
                RetargetOptions {
                    start_frame: 1,
                    ..RetargetOptions::default()
                },
            ),
            (
                "cmu_13_29_squats_excerpt_f3792-4592.bvh",
                Some(traffic.clone()),
                RetargetOptions::default(),
            ),
        ] {
            cases.push((g1.clone(), mocap.join(clip), calibration, options));
        }
    }
    println!(
        "{:<10} {:<40} {:>6} {:>10} {:>10} {:>10} {:>13} {:>12}",
        "robot", "clip", "frames", "median ms", "p99 ms", "max ms", "slide cm/s", "hands cm RMS"
    );
    for (robot, clip, calibration, options) in cases {
        let robot = Robot::load(&robot).unwrap();
        let bvh = Bvh::load(&clip).unwrap();
        let calibration = calibration.map(|c| Bvh::load(&c).unwrap());
        let m = retarget_calibrated(&robot, &bvh, calibration.as_ref().unwrap_or(&bvh), &options).unwrap();
        let r = &m.report;
        let hands: Vec<f64> = r
            .key_bodies
            .iter()
            .filter(|k| {
                matches!(
                    k.human,
                    robots::HumanBody::LeftHand | robots::HumanBody::RightHand
                )
            })
            .map(|k| 100.0 * k.rms)
            .collect();
        println!(
            "{:<10} {:<40} {:>6} {:>10.3} {:>10.3} {:>10.3} {:>13.2} {:>12}",
            robot.config.name,
            clip.file_name().unwrap().to_string_lossy(),
            r.frames,
            1e3 * r.frame_time.median,
            1e3 * r.frame_time.p99,
            1e3 * r.frame_time.max,
            100.0 * r.foot_sliding.median,
            hands
                .iter()
                .map(|h| format!("{h:.1}"))
                .collect::<Vec<_>>()
                .join("/")
        );
    }
}
