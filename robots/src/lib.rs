//! Robot descriptions: which joints a robot has, on which bus and device each sits, its limits,
//! default pose and gains, as typed data loaded from `robot.toml` beside the robot's MJCF.
