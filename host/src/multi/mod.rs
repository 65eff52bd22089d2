//! Several scalar magnetometers at once (issue 19; docs/model.md §7,
//! docs/trace-format.md "Several magnetometers"): one anomaly shared by every sensor, each
//! sensor its own interference, and the gradients between them.

pub mod joint;
pub mod lever;
pub mod sensors;

pub use joint::{apply_each, calibrate_joint, JointResult, SensorResult};
pub use sensors::{parse_pairs, parse_sensors, sensor_trace, separation_m, SensorSpec};
