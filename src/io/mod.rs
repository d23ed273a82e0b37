//! Input and output of the navigation core: the sensor log format used to record flights
//! (and to replay them), the camera frame stream from the vehicle, and (feature `daemon`) the
//! MAVLink mapping of the daemon (messages in and out, time synchronisation) and the MCAP
//! export of a log.

pub mod frame_stream;
#[cfg(feature = "daemon")]
pub mod mavlink_in;
#[cfg(feature = "daemon")]
pub mod mavlink_out;
#[cfg(feature = "daemon")]
pub mod mcap_export;
pub mod sensor_log;
#[cfg(feature = "daemon")]
pub mod timesync;
