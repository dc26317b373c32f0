//! The corpus's scenes: what `synth` makes of each, and the filters each is tracked with.

use std::path::Path;

use firmware_sim::sim::scenario::ScenarioName;
use protocol::ModelKind;
use serde::Serialize;

use crate::synth::{FrameOptions, Shading, SynthOptions, scene::UNTEXTURED_COLOUR};

/// A solid blue whose grey (BT.601 luma 0.25) lies well below the generated textures' grey
/// levels: an untextured object that stands out, beside [`UNTEXTURED_COLOUR`]'s, which does
/// not.
pub const FAR_COLOUR: [f32; 3] = [0.10, 0.20, 0.90];

/// One scene of the corpus.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Scene {
    /// Its name in the tables and the output folders.
    pub name: &'static str,
    /// What it tries to break.
    pub tries: &'static str,
    /// The scenario (camera path, IMU, target, lighting, occluders).
    #[serde(serialize_with = "scenario_name")]
    pub scenario: ScenarioName,
    /// The modelled surfaces in one colour, without texture.
    pub untextured: Option<[f32; 3]>,
    /// A frame every this many IMU samples (100 Hz): 4 is the scenarios' 25 Hz; 16 moves the
    /// object four times as far between frames (RBOT's large-motion variant).
    pub every: u32,
    /// Its length in the quick form [s] (the full form takes the scenario's own).
    pub quick_s: f64,
    /// In the quick form too (the suite's).
    pub quick: bool,
    /// A mesh in place of the modelled surfaces, under the shared data folder (`--data`).
    pub object: Option<&'static str>,
    /// Lit, shaded frames ([`crate::synth::Shading`]'s default light).
    pub lit: bool,
}

/// The Stanford bunny, a scanned shape without texture, 15 cm tall.
const BUNNY: Option<&str> = Some("meshes/bunny/bunny.obj");

/// The fields every scene but a few shares: desk-fast, textured, 25 Hz, unlit.
const DESK_FAST: Scene = Scene {
    name: "",
    tries: "",
    scenario: ScenarioName::DesktopFast,
    untextured: None,
    every: 4,
    quick_s: 3.0,
    quick: false,
    object: None,
    lit: false,
};

fn scenario_name<S: serde::Serializer>(s: &ScenarioName, ser: S) -> Result<S::Ok, S::Error> {
    ser.serialize_str(s.as_str())
}

/// Every scene, in the order of the tables.
pub const SCENES: &[Scene] = &[
    Scene {
        name: "desk-slow",
        tries: "nothing: the paper's slow figure eight, textured",
        scenario: ScenarioName::DesktopSlow,
        ..DESK_FAST
    },
    Scene {
        name: "desk-fast",
        tries: "fast motion, vibration, motion blur, light changes; textured",
        quick: true,
        ..DESK_FAST
    },
    Scene {
        name: "desk-fast-lit",
        tries: "a lamp that turns and dims: the faces' brightness changes with it",
        lit: true,
        ..DESK_FAST
    },
    Scene {
        name: "desk-fast-large-motion",
        tries: "a frame every 16 samples (6.25 Hz): four times the motion between frames",
        every: 16,
        quick_s: 4.0,
        quick: true,
        ..DESK_FAST
    },
    Scene {
        name: "desk-fast-untextured-near",
        tries: "an untextured object whose grey is that of its surroundings",
        untextured: Some(UNTEXTURED_COLOUR),
        quick: true,
        ..DESK_FAST
    },
    Scene {
        name: "desk-fast-untextured-far",
        tries: "an untextured object far darker than its surroundings",
        untextured: Some(FAR_COLOUR),
        ..DESK_FAST
    },
    Scene {
        name: "bunny-lit-near",
        tries: "a scanned shape, shaded by a turning lamp, its grey that of its surroundings",
        untextured: Some(UNTEXTURED_COLOUR),
        object: BUNNY,
        lit: true,
        ..DESK_FAST
    },
    Scene {
        name: "bunny-lit-far",
        tries: "a scanned shape, shaded by a turning lamp, far darker than its surroundings",
        untextured: Some(FAR_COLOUR),
        object: BUNNY,
        lit: true,
        ..DESK_FAST
    },
    Scene {
        name: "room",
        tries: "a hand-held walk among three textured walls, unmodelled clutter, occluders",
        scenario: ScenarioName::Room,
        ..DESK_FAST
    },
    Scene {
        name: "foyer",
        tries: "a wall 7 m away: depth weakly seen, rotation against translation",
        scenario: ScenarioName::Foyer,
        ..DESK_FAST
    },
];

/// The filters each scene is tracked with: the IMU's acceleration model, and vision alone.
pub const FILTERS: [ModelKind; 2] = [ModelKind::Acc, ModelKind::Vision];

impl Scene {
    /// The synthesis options of the scene (`quick`: its quick length), written to `out`, its
    /// object under the shared data folder `data`.
    pub fn synth_options(
        &self,
        out: std::path::PathBuf,
        data: &Path,
        quick: bool,
        seed: u64,
    ) -> SynthOptions {
        let mut o = SynthOptions::new(self.scenario, out);
        o.object = self.object.map(|p| data.join(p));
        o.seed = seed;
        o.duration = quick.then_some(self.quick_s);
        o.rates = (self.every != 4).then_some((100.0, self.every));
        o.frames = FrameOptions::new(320, 240);
        o.frames.shading = self.lit.then(Shading::default);
        o.textures.untextured = self.untextured;
        o.overwrite = true;
        o
    }

    /// The name of its cached dataset: every option that changes it.
    pub fn dataset_name(&self, quick: bool, seed: u64) -> String {
        let length = if quick {
            format!("{}s", self.quick_s)
        } else {
            "full".into()
        };
        format!("corpus-{}-{length}-seed{seed}", self.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scene_names_are_distinct_and_the_quick_form_has_some() {
        let mut names: Vec<_> = SCENES.iter().map(|s| s.name).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), SCENES.len());
        assert!(SCENES.iter().filter(|s| s.quick).count() >= 3);
    }

    #[test]
    fn every_scene_synthesises_with_valid_options() {
        for s in SCENES {
            let o = s.synth_options("x".into(), Path::new("data"), true, 0);
            o.frames.validate().unwrap();
            o.build_scenario().unwrap();
            assert!(s.dataset_name(true, 0) != s.dataset_name(false, 0));
        }
    }
}
