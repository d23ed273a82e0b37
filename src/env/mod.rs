//! Environment models shared by the INS and the simulator: the ISA atmosphere with
//! temperature and pressure offsets, and the Earth magnetic field (World Magnetic Model).

pub mod atmosphere;
pub mod magnetic;
