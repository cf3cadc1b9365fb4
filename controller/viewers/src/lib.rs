//! What viewers get of a run, beside the typed messages the loop records: the robot in 3D from
//! its MJCF (`robot3d`: scene entities and per-link frames), the Foxglove layout per robot
//! (`layout`), and the live Foxglove WebSocket server (`live`). Nothing of the loop: the
//! controller's telemetry sink hands encoded messages and joint positions in.

pub mod layout;
pub mod live;
pub mod robot3d;
pub mod urdf;

use foxglove::schemas as fg;

/// `[x, y, z, qw, qx, qy, qz]` as a Foxglove pose.
pub fn fg_pose(p: [f64; 7]) -> fg::Pose {
    fg::Pose {
        position: Some(fg::Vector3 {
            x: p[0],
            y: p[1],
            z: p[2],
        }),
        orientation: Some(fg::Quaternion {
            x: p[4],
            y: p[5],
            z: p[6],
            w: p[3],
        }),
    }
}

/// A time in ns as a Foxglove timestamp (seconds saturate at `u32::MAX`).
pub fn fg_time(ns: u64) -> Option<fg::Timestamp> {
    let sec = u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX);
    Some(fg::Timestamp::new(sec, (ns % 1_000_000_000) as u32))
}
