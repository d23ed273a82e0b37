//! Input and output of the navigation core: the sensor log format used to record flights
//! (and to replay them), and the camera frame stream from the vehicle.

pub mod frame_stream;
pub mod sensor_log;
