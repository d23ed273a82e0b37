//! `[navigation]` of the daemon's configuration: the INS and vision settings files, the
//! magnetic model epoch, the fused solution's visual position and the vision thread.

use serde::Deserialize;

/// `[navigation]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NavigationConfig {
    /// Path of an INS configuration (`config/ins.toml` format), relative to this file's
    /// directory. Empty: the inline `[ins]` table, or the defaults.
    #[serde(default)]
    pub ins_config: String,
    /// Epoch of the magnetic model, decimal year; 0 = from the system clock at start.
    #[serde(default)]
    pub mag_decimal_year: f64,
    /// Path of the visual navigation's settings (`config/vision.toml` format), relative to
    /// this file's directory. Empty: the inline `[vision]` table, or the defaults (for the
    /// paper's 768 × 1024 camera: scale the pixel settings for another size, docs/CAMERA.md).
    #[serde(default)]
    pub vision_config: String,
    /// With a camera: after the GNSS loss, publish the IA-VNS's horizontal position (carried
    /// between frames by the INS) instead of the INS's (docs/FUSION.md). Off: the IA-VNS runs
    /// and is logged, the INS is published.
    #[serde(default = "yes")]
    pub vision_position: bool,
    /// `[navigation.vision_error]`: the visual position's error model (docs/FUSION.md).
    #[serde(default)]
    pub vision_error: crate::nav::fusion::FusionConfig,
    /// `[navigation.vision_restart]`: when the visual navigation starts over from the fused
    /// pose (docs/FUSION.md).
    #[serde(default)]
    pub vision_restart: crate::nav::VisionRestart,
    /// How the vision thread is scheduled beside the IMU path (docs/DAEMON.md "Threads").
    #[serde(default)]
    pub vision_thread: VisionThreadPolicy,
}

/// `navigation.vision_thread`: the vision thread's scheduling policy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VisionThreadPolicy {
    /// `SCHED_IDLE`: it runs only when no other thread of the core wants to, so a woken IMU
    /// path takes the core at once (otherwise the kernel lets the vision finish its time slice,
    /// about 2 ms). On a core shared with busy processes the vision gets only what they leave
    /// (frames then show as `frames_vision_busy`): use `normal` there.
    #[default]
    Idle,
    /// The default policy of the process.
    Normal,
}

fn yes() -> bool {
    true
}

impl Default for NavigationConfig {
    fn default() -> Self {
        Self {
            ins_config: String::new(),
            mag_decimal_year: 0.0,
            vision_config: String::new(),
            vision_position: true,
            vision_error: crate::nav::fusion::FusionConfig::default(),
            vision_restart: crate::nav::VisionRestart::default(),
            vision_thread: VisionThreadPolicy::default(),
        }
    }
}
