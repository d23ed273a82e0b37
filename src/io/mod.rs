//! Input and output of the navigation core: the sensor log format used to record flights
//! (and to replay them), the camera frame stream from the vehicle, and the MAVLink mapping
//! (messages in and out, time synchronisation) of the daemon.

pub mod frame_stream;
pub mod mavlink_in;
pub mod mavlink_out;
pub mod sensor_log;
pub mod timesync;
