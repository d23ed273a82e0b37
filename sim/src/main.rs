//! `ianav-sim`: fly scenarios with the navigation in the loop.

fn main() {
    println!("ianav-sim {}", env!("CARGO_PKG_VERSION"));
}
