//! The visual systems a camera flight runs on the same frames (docs/IAVNS.md "One flight, every
//! system"): the paper's VNS and IA-VNS, and the ablation's variants, each the flight's vision
//! settings with the IA-VNS's switches (`vision.aiding`) set its way. Rendering each frame once
//! for all of them is what makes their comparison one of identical flights.

use ianav::nav::ComparedVision;
use ianav::vision::iavns::activation::AdjustmentMode;
use ianav::vision::vns::VnsConfig;

/// A named visual system: the flight's vision settings with the IA-VNS's switches set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum VisionSystem {
    /// The paper's VNS: every IA-VNS change off.
    #[value(name = "vns")]
    Vns,
    /// The paper's IA-VNS: every change on, pitch and bank activation.
    #[value(name = "ia-vns")]
    IaVns,
    /// The IA-VNS with the pitch-only activation mode.
    #[value(name = "ia-vns-pitch")]
    IaVnsPitch,
    /// The IA-VNS with the full-attitude SLERP activation (beyond the paper).
    #[value(name = "ia-vns-slerp")]
    IaVnsSlerp,
    /// The VNS plus the INS initialisation alone.
    #[value(name = "vns+init")]
    VnsInit,
    /// The VNS plus `ζ*` from the INS alone.
    #[value(name = "vns+prediction")]
    VnsPrediction,
    /// The VNS plus the priors alone.
    #[value(name = "vns+priors")]
    VnsPriors,
    /// The VNS plus the current frame's features in structure optimisation alone.
    #[value(name = "vns+structure")]
    VnsStructure,
    /// The flight's vision settings as they are (`vision.toml`), switches included.
    #[value(name = "config")]
    Config,
}

/// What camera flights run when not told: the paper's two systems.
pub const DEFAULT_VISION_SYSTEMS: [VisionSystem; 2] = [VisionSystem::Vns, VisionSystem::IaVns];

/// The ablation's systems (docs/RESULTS.md "Ablation").
pub const ABLATION_VISION_SYSTEMS: [VisionSystem; 8] = [
    VisionSystem::Vns,
    VisionSystem::VnsInit,
    VisionSystem::VnsPrediction,
    VisionSystem::VnsPriors,
    VisionSystem::VnsStructure,
    VisionSystem::IaVns,
    VisionSystem::IaVnsPitch,
    VisionSystem::IaVnsSlerp,
];

impl VisionSystem {
    /// Every system, in the order of the enum.
    pub const ALL: [Self; 9] = [
        Self::Vns,
        Self::IaVns,
        Self::IaVnsPitch,
        Self::IaVnsSlerp,
        Self::VnsInit,
        Self::VnsPrediction,
        Self::VnsPriors,
        Self::VnsStructure,
        Self::Config,
    ];

    /// Its name in run files, reports and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Vns => "vns",
            Self::IaVns => "ia-vns",
            Self::IaVnsPitch => "ia-vns-pitch",
            Self::IaVnsSlerp => "ia-vns-slerp",
            Self::VnsInit => "vns+init",
            Self::VnsPrediction => "vns+prediction",
            Self::VnsPriors => "vns+priors",
            Self::VnsStructure => "vns+structure",
            Self::Config => "config",
        }
    }

    /// The system of a name written by [`VisionSystem::name`].
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }

    /// Its settings: `base` with the switches set (the activation and prior settings of
    /// `base` are kept, so `vision.toml` tunes the IA-VNS's).
    pub fn config(self, base: &VnsConfig) -> VnsConfig {
        let mut cfg = base.clone();
        let a = &mut cfg.aiding;
        let set = |a: &mut ianav::vision::vns::AidingConfig,
                   [init, prediction, priors, structure]: [bool; 4]| {
            a.inertial_initialisation = init;
            a.inertial_prediction = prediction;
            a.priors = priors;
            a.current_features_in_structure = structure;
        };
        match self {
            Self::Vns => set(a, [false; 4]),
            Self::IaVns => {
                set(a, [true; 4]);
                a.activation.mode = AdjustmentMode::PitchBank;
            }
            Self::IaVnsPitch => {
                set(a, [true; 4]);
                a.activation.mode = AdjustmentMode::Pitch;
            }
            Self::IaVnsSlerp => {
                set(a, [true; 4]);
                a.activation.mode = AdjustmentMode::Slerp;
            }
            Self::VnsInit => set(a, [true, false, false, false]),
            Self::VnsPrediction => set(a, [false, true, false, false]),
            Self::VnsPriors => set(a, [false, false, true, false]),
            Self::VnsStructure => set(a, [false, false, false, true]),
            Self::Config => {}
        }
        cfg
    }
}

/// The navigator's settings for `systems` over `base`: the first is its configured system,
/// the others run beside it. `None` for an empty list.
pub fn navigator_vision(
    systems: &[VisionSystem],
    base: &VnsConfig,
) -> Option<(VnsConfig, Vec<ComparedVision>)> {
    let (first, rest) = systems.split_first()?;
    let compared = rest
        .iter()
        .map(|s| ComparedVision {
            name: s.name().to_owned(),
            vision: s.config(base),
        })
        .collect();
    Some((first.config(base), compared))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_the_paper_systems_are_what_the_paper_says() {
        for s in VisionSystem::ALL {
            assert_eq!(VisionSystem::from_name(s.name()), Some(s));
        }
        let mut base = VnsConfig {
            aiding: ianav::vision::vns::AidingConfig::paper(),
            ..VnsConfig::default()
        };
        base.pose.max_iterations = 7;
        assert!(!VisionSystem::Vns.config(&base).aiding.any());
        assert_eq!(VisionSystem::Vns.config(&base).pose.max_iterations, 7);
        let base_off = VnsConfig::default();
        assert_eq!(
            VisionSystem::IaVns.config(&base_off).aiding,
            ianav::vision::vns::AidingConfig::paper()
        );
        assert_eq!(VisionSystem::Config.config(&base), base);
        // Each ablation variant switches exactly one change on.
        for s in [
            VisionSystem::VnsInit,
            VisionSystem::VnsPrediction,
            VisionSystem::VnsPriors,
            VisionSystem::VnsStructure,
        ] {
            let a = s.config(&base).aiding;
            let on = [
                a.inertial_initialisation,
                a.inertial_prediction,
                a.priors,
                a.current_features_in_structure,
            ];
            assert_eq!(on.iter().filter(|x| **x).count(), 1, "{s:?}");
        }
        let (first, rest) = navigator_vision(&DEFAULT_VISION_SYSTEMS, &base_off).unwrap();
        assert!(!first.aiding.any());
        assert_eq!(rest.len(), 1);
        assert_eq!(rest[0].name, "ia-vns");
        assert!(navigator_vision(&[], &base_off).is_none());
    }
}
