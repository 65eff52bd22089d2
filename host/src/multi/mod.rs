//! Several scalar magnetometers at once (issue 19; docs/model.md §7,
//! docs/trace-format.md "Several magnetometers"): one anomaly shared by every sensor, each
//! sensor its own interference, and the gradients between them.

mod choice;
pub mod joint;
mod joint_pass;
pub mod lever;
mod result;
pub mod sensors;

pub use joint::{apply_each, calibrate_joint};
pub use result::{JointResult, SensorResult};
pub use sensors::{parse_pairs, parse_sensors, sensor_trace, separation_m, SensorSpec};
