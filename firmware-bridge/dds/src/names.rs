//! Topic and type names as ROS 2's DDS middlewares put them on the wire: a topic `/joint_states`
//! is the DDS topic `rt/joint_states`; a type `sensor_msgs/msg/JointState` is the DDS type
//! `sensor_msgs::msg::dds_::JointState_`. Unitree's SDK names its topics the same way
//! (`rt/lowstate`, `unitree_hg::msg::dds_::LowState_`).

/// The DDS topic of a ROS 2 topic (`/joint_states` → `rt/joint_states`).
pub fn ros2_topic(ros_topic: &str) -> String {
    format!("rt/{}", ros_topic.trim_start_matches('/'))
}

/// The DDS type of a ROS 2 message type (`sensor_msgs/msg/JointState` →
/// `sensor_msgs::msg::dds_::JointState_`).
pub fn ros2_type(ros_type: &str) -> String {
    match ros_type.rsplit_once('/') {
        Some((namespace, name)) => format!("{}::dds_::{name}_", namespace.replace('/', "::")),
        None => format!("{ros_type}_"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ros2_names_map_as_the_middlewares_do() {
        assert_eq!(ros2_topic("/joint_states"), "rt/joint_states");
        assert_eq!(ros2_topic("tf"), "rt/tf");
        assert_eq!(
            ros2_type("sensor_msgs/msg/JointState"),
            "sensor_msgs::msg::dds_::JointState_"
        );
        assert_eq!(
            ros2_type("unitree_hg/msg/LowCmd"),
            "unitree_hg::msg::dds_::LowCmd_"
        );
    }
}
