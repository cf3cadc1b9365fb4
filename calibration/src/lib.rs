//! Calibration procedures: servo zero offsets and directions, IMU mounting, identity checks, and the
//! human side of retargeting (T-pose scale and device offsets). Results are files the controller
//! merges at start-up.
