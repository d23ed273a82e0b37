//! Input and output of the navigation core: the sensor log format used to record flights
//! (and, later, to replay them and to feed the daemon's tests).

pub mod sensor_log;
