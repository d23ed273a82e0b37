//! A flight's sensor log replayed through the navigation core gives that flight's navigation
//! solutions bit for bit: the log holds every event the flight fed its navigator (the start
//! alignment included) and the navigator's settings, and the core is deterministic.

use std::collections::BTreeMap;

use ianav::io::sensor_log::{SensorLogReader, SensorLogWriter};
use ianav::nav::NavSolution;
use ianav::nav::replay::{config_of, config_to_toml, replay};
use ianav::sensors::SensorEvent;
use ianav_sim::flight::{Flight, FlightObserver, FlightSetup, TruthSample};

/// Records every sensor event into an in-memory log and the solutions the flight saw.
struct Recorder {
    log: SensorLogWriter<Vec<u8>>,
    seen: Vec<NavSolution>,
}

impl FlightObserver for Recorder {
    fn sensor_event(&mut self, event: &SensorEvent) {
        self.log.write(event).expect("writing to memory");
    }
    fn nav_solution(&mut self, _truth: &TruthSample, sol: &NavSolution) {
        self.seen.push(*sol);
    }
}

#[test]
fn replaying_a_flights_sensor_log_gives_its_solutions_bit_for_bit() {
    let mut setup = FlightSetup::builtin(2).unwrap();
    // Through the GNSS loss at 100 s and 20 s of dead reckoning.
    setup.scenario.duration_s = 120.0;
    let mut flight = Flight::new(&setup, 7).unwrap();
    let cfg = flight.navigator().unwrap().config().clone();
    let mut log = SensorLogWriter::new(Vec::new()).unwrap();
    log.write_nav_config(&config_to_toml(&cfg)).unwrap();
    let mut rec = Recorder {
        log,
        seen: Vec::new(),
    };
    flight.run(&mut rec, |_| {}).unwrap();
    let bytes = rec.log.finish().unwrap();

    let reader = SensorLogReader::new(&bytes[..]).unwrap();
    assert_eq!(config_of(&reader).unwrap(), cfg);
    let mut replayed = BTreeMap::new();
    let summary = replay(reader, &cfg, |sol| {
        replayed.insert(sol.t_us, *sol);
        Ok(())
    })
    .unwrap();
    assert_eq!(summary.nav.initialisations, 1);
    assert!(rec.seen.len() > 1_500, "{} solutions seen", rec.seen.len());
    assert!(rec.seen.last().unwrap().ins_status.gnss_denied);
    for sol in &rec.seen {
        // The whole solution, INS detail and covariances included.
        assert_eq!(replayed.get(&sol.t_us), Some(sol), "at {} µs", sol.t_us);
    }
}
