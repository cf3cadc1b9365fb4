//! DDS samples from the network: Unitree's `rt/lowcmd`/`rt/lowstate` (the board and the host read
//! them) and ROS 2's `/cmd_vel` (`play --cmd-vel`). Any bytes through the CDR readers: an accepted
//! message reads back the same from its own CDR; the emulated board takes a command only with a
//! right CRC; a Twist's commands are finite and within the manifest's ranges.

use firmware_bridge::mit::firmware::MitFirmwareConfig;
use firmware_bridge::mit::models::find;
use firmware_bridge::time::SimInstant;
use firmware_bridge::unitree::board::{BoardConfig, BoardMotor, CommandVerdict, UnitreeBoard};
use firmware_bridge::unitree::hg::{LowCmd, LowState, Sealed as _};
use human::commands::twist_commands;

/// One input.
pub fn run(data: &[u8]) {
    let mut cdr = Vec::new();
    if let Ok(cmd) = LowCmd::read_cdr(data) {
        cmd.write_cdr(&mut cdr);
        assert_eq!(LowCmd::read_cdr(&cdr).map(|c| c.crc_ok()), Ok(cmd.crc_ok()));
    }
    if let Ok(state) = LowState::read_cdr(data) {
        state.write_cdr(&mut cdr);
        assert_eq!(LowState::read_cdr(&cdr).map(|s| s.tick), Ok(state.tick));
    }
    let mut board = UnitreeBoard::new(
        BoardConfig {
            motors: vec![BoardMotor {
                slot: 3,
                firmware: MitFirmwareConfig::new(3, find("AK80-9").expect("a shipped model")),
            }],
            state_period: std::time::Duration::from_millis(2),
            mode_machine: 5,
            supply_voltage: 48.0,
        },
        SimInstant::ZERO,
    );
    if board.receive(SimInstant::ZERO, data) == CommandVerdict::Accepted {
        assert!(LowCmd::read_cdr(data).is_ok_and(|c| c.crc_ok()));
    }
    if let Ok(twist) = dds::ros2::decode_twist(data) {
        // Exactly a Twist's bytes: a longer blob is no Twist.
        assert_eq!(data.len(), dds::ros2::TWIST_BYTES);
        let spec = crate::walk_commands();
        let mut out = [0.0; 3];
        twist_commands(&spec, &spec.kinds(), twist, &mut out);
        assert!(spec.check_values(&out).is_ok(), "{out:?} from {twist:?}");
    }
}
