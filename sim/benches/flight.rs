//! Criterion benches of the simulator: the cost of one second of flight (500 integration
//! steps with the environment, 100 Hz sensors and 50 Hz control), the budget behind the
//! "≥ 1,000× real time" target. `ianav-sim bench` times whole scenarios.

use std::hint::black_box;

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use ianav_sim::flight::{Flight, FlightSetup, NavigationMode, NoObserver};

fn one_second_of_flight(c: &mut Criterion) {
    // The simulator alone (the INS has its own bench, benches/ins.rs in the ianav crate).
    let mut setup = FlightSetup::builtin(1).expect("built-in scenario");
    setup.navigation = NavigationMode::Truth;
    c.bench_function("flight/1 s of scenario #1 (500 steps)", |b| {
        b.iter_batched(
            || Flight::new(&setup, 1).expect("flight set-up"),
            |mut flight| {
                for _ in 0..500 {
                    flight
                        .step(&mut NoObserver)
                        .expect("flight stays in the envelope");
                }
                black_box(flight.truth().pos)
            },
            BatchSize::LargeInput,
        );
    });
}

criterion_group!(benches, one_second_of_flight);
criterion_main!(benches);
