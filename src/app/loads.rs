//! Every model load of the page, owned by the core: which weight files each model set needs,
//! where its load stands ([`Load`]), and what the page falls back to when it fails (the
//! procedural world, the 32 m world, the band interpolation), in words for the user.

use crate::models::tem::{LEVELS, weight_file};
use crate::world::learned::{GROW_FILE, TCM_FILE};

/// A set of models the page loads together.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ModelSet {
    /// The TEM ladder (learned detail below 32 m), five files.
    Tem,
    /// The learned world (TCM and ×4 step).
    World,
    /// The sketch generator and VAE (loaded once the sketch world is first shown).
    Sketch,
}

impl ModelSet {
    /// The set's weight files, in the order the runner takes them.
    pub fn files(self) -> Vec<String> {
        match self {
            ModelSet::Tem => (0..LEVELS).map(weight_file).collect(),
            ModelSet::World => vec![TCM_FILE.into(), GROW_FILE.into()],
            ModelSet::Sketch => vec![crate::models::sketch::WEIGHT_FILE.into(), crate::models::sketch_vae::WEIGHT_FILE.into()],
        }
    }
}

/// Where one model set's load stands.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Load {
    /// Not asked for yet.
    #[default]
    Idle,
    /// Its files are downloading: `done` of `total` arrived.
    Fetching {
        /// Files arrived.
        done: usize,
        /// Files in all.
        total: usize,
    },
    /// The files arrived; the runner is reading them (and, on a GPU, compiling its kernels).
    Loading,
    /// Ready: the short hash of its weight files and where it runs ("WebGPU", "CPU …").
    Ready {
        /// [`crate::models::weights_hash`] of the files.
        hash: String,
        /// Where the models run, for the overlay.
        backend: String,
    },
    /// Not available: why, for the user.
    Failed(String),
}

impl Load {
    /// Whether the set is ready.
    pub fn is_ready(&self) -> bool {
        matches!(self, Load::Ready { .. })
    }

    /// Whether the set's load has ended, well or not.
    pub fn is_settled(&self) -> bool {
        matches!(self, Load::Ready { .. } | Load::Failed(_))
    }
}

/// The three loads of the page.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Loads {
    /// The TEM.
    pub tem: Load,
    /// The learned world.
    pub world: Load,
    /// The sketch models.
    pub sketch: Load,
}

impl Loads {
    /// The load of `set`.
    pub fn get(&self, set: ModelSet) -> &Load {
        match set {
            ModelSet::Tem => &self.tem,
            ModelSet::World => &self.world,
            ModelSet::Sketch => &self.sketch,
        }
    }

    /// The load of `set`, to change.
    pub fn get_mut(&mut self, set: ModelSet) -> &mut Load {
        match set {
            ModelSet::Tem => &mut self.tem,
            ModelSet::World => &mut self.world,
            ModelSet::Sketch => &mut self.sketch,
        }
    }
}

/// Why a load failed, as the reason shown to the user.
#[derive(Clone, Debug, PartialEq)]
pub enum LoadError {
    /// A weight file could not be downloaded (the URL and the browser's reason).
    Fetch(String),
    /// The runner read the files and refused them (which file and why).
    Broken(String),
    /// The CPU worker is gone (the browser's reason).
    WorkerStopped(String),
    /// The set needs a Web Worker and the browser gave none.
    NoWorker(String),
    /// The models failed while in use (the whole reason, as is).
    Failed(String),
    /// The models loaded but failed when run on `backend`.
    Run {
        /// Where they ran.
        backend: String,
        /// Why they failed.
        why: String,
    },
}

/// The reason a failed load gives, in the words of the set's fallback: the TEM's end in
/// "showing the 32 m world"; the world's and the sketch's are completed by [`notice`].
pub fn reason(set: ModelSet, e: &LoadError) -> String {
    match (set, e) {
        (ModelSet::Tem, LoadError::Fetch(e)) => format!("TEM weights could not be loaded ({e}); showing the 32 m world"),
        (ModelSet::Tem, LoadError::Broken(e)) => format!("TEM weights are broken ({e}); showing the 32 m world"),
        (ModelSet::Tem, LoadError::WorkerStopped(e)) => format!("The CPU worker stopped ({e}); showing the 32 m world"),
        (ModelSet::Tem, LoadError::Run { backend, why }) => format!("TEM failed on {backend} ({why}); showing the 32 m world"),
        (ModelSet::Tem, LoadError::NoWorker(e)) => format!("TEM needs a worker ({e}); showing the 32 m world"),
        (ModelSet::Tem, LoadError::Failed(e)) => format!("{e}; showing the 32 m world"),
        (_, LoadError::Fetch(e)) => format!("its weights could not be loaded ({e})"),
        (_, LoadError::Broken(e)) => format!("its weights are broken ({e})"),
        (_, LoadError::WorkerStopped(e)) => format!("the CPU worker stopped ({e})"),
        (_, LoadError::NoWorker(e)) => format!("it needs a Web Worker ({e})"),
        (_, LoadError::Run { backend, why }) => format!("it failed on {backend} ({why})"),
        (_, LoadError::Failed(e)) => e.clone(),
    }
}

/// The page's message when `set` is not available for `why` (the TEM's failure shows in the
/// overlay's detail line instead: `None`).
pub fn notice(set: ModelSet, why: &str) -> Option<String> {
    match set {
        ModelSet::Tem => None,
        ModelSet::World => Some(format!("The learned world is not available: {why}. Showing the procedural world.")),
        ModelSet::Sketch => Some(format!("The sketch generator is not available: {why}. Showing the band interpolation instead.")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each set names its files (5 TEM levels, 2 world, 2 sketch) and every failure reads as
    /// what the user sees instead: the 32 m world, the procedural world, the band interpolation.
    #[test]
    fn each_set_names_its_files_and_its_fallback_in_every_failure() {
        assert_eq!(ModelSet::Tem.files().len(), LEVELS);
        assert_eq!(ModelSet::World.files(), vec![TCM_FILE.to_string(), GROW_FILE.to_string()]);
        assert_eq!(ModelSet::Sketch.files().len(), 2);
        let errors = [
            LoadError::Failed("x".into()),
            LoadError::Fetch("x".into()),
            LoadError::Broken("x".into()),
            LoadError::WorkerStopped("x".into()),
            LoadError::NoWorker("x".into()),
            LoadError::Run { backend: "WebGPU".into(), why: "x".into() },
        ];
        for e in &errors {
            assert!(reason(ModelSet::Tem, e).ends_with("showing the 32 m world"), "{e:?}");
            assert!(notice(ModelSet::World, &reason(ModelSet::World, e)).unwrap().ends_with("Showing the procedural world."));
            assert!(notice(ModelSet::Sketch, &reason(ModelSet::Sketch, e)).unwrap().ends_with("Showing the band interpolation instead."));
        }
        assert_eq!(notice(ModelSet::Tem, "x"), None);
        assert!(Load::Ready { hash: "h".into(), backend: "b".into() }.is_settled() && !Load::Loading.is_settled());
    }
}
