use sim2real::host::MirrorHost;
use sim2real::config::MirrorConfig;
#[test]
fn debug_cycles() {
    let robot = robots::Robot::load(&robots::reference_robot_path()).unwrap();
    let mut host = MirrorHost::start(robot.clone(), MirrorConfig::default()).unwrap();
    let q: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let start = host.now();
    for k in 1..5u32 {
        host.command_positions(&robot, &q).unwrap();
        host.wait_until(start + std::time::Duration::from_millis(20) * k);
        eprintln!("missed {:?} age {:?}", host.state().missed, host.state().age);
    }
}
