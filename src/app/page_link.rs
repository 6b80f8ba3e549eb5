//! The page's link: the view it opens, the address bar's fragment, "Copy link".

use super::PageCore;
use crate::share::ShareState;
use crate::sketch::Sketch;

/// The link: the address bar's fragment and "Copy link".
impl PageCore {
    /// The view to open and its message: `restart`'s (the view kept after a lost device),
    /// else the link in `fragment` (a version-1 link says its world may differ; a broken one
    /// opens the default world and says why), else `options_notice`.
    pub fn opening_view(restart: Option<(ShareState, String)>, fragment: &str, options_notice: Option<String>) -> (ShareState, Option<String>) {
        match (restart, ShareState::from_fragment(fragment)) {
            (Some((state, note)), _) => (state, Some(note)),
            (None, Ok(s)) if s.link_version == 1 => (
                s,
                Some(
                    "This link is from an older version of the page (version 1): it opens the procedural world it was made with, which may differ from what its sender saw.".into(),
                ),
            ),
            (None, Ok(s)) => (s, options_notice),
            (None, Err(e)) => (ShareState::default(), Some(format!("{e}. Showing the default world instead."))),
        }
    }

    /// Takes `fragment` as the address bar's fragment the page opened with (not followed again).
    pub fn opened_at(mut self, fragment: String) -> Self {
        self.link.0 = fragment;
        self
    }

    /// The address bar's fragment is `fragment`: a new one (a link opened in this same page)
    /// is applied and returned, for the overlay; a broken one keeps the world and says so.
    pub fn follow_link(&mut self, fragment: &str) -> Option<ShareState> {
        if fragment == self.link.0 {
            return None;
        }
        self.link.0 = fragment.to_string();
        match ShareState::from_fragment(fragment) {
            Ok(s) => {
                self.app.apply(s.clone());
                if let Some(note) = self.app.linked_weights_note() {
                    self.message = Some(note);
                }
                Some(s)
            }
            Err(e) => {
                self.message = Some(format!("{e}. Keeping the current world."));
                None
            }
        }
    }

    /// The fragment to write into the address bar now (`#…`), so that copying the address
    /// shares the view: at most once a second, and only when it changed. `force` skips the wait.
    /// It keeps the world the user asked for ([`TerrainApp::asked_state`]); "Copy link"
    /// gives the world shown.
    pub fn link_to_write(&mut self, now_ms: f64, force: bool) -> Option<String> {
        if !force && now_ms - self.link.1 < 1000.0 {
            return None;
        }
        self.link.1 = now_ms;
        let fragment = format!("#{}", self.app.asked_state().to_fragment());
        (fragment != self.link.0).then(|| {
            self.link.0 = fragment.clone();
            fragment
        })
    }

    /// "Copy link" on page address `page`: the text to copy, and the sketch to send as a file
    /// when it is too detailed for a link (the link then carries everything else, and the
    /// message says to send both).
    pub fn copy_link(&mut self, page: &str) -> (String, Option<Sketch>) {
        match self.app.share_state().share_fragment() {
            Ok(f) => (format!("{page}#{f}"), None),
            Err(too_long) => {
                self.message = Some(format!(
                    "{too_long}. The link copied has everything but the sketch, which was downloaded as sketch.png: send both; the receiver opens the link, then Import PNG."
                ));
                (format!("{page}#{}", too_long.without_sketch), Some(self.app.canvas.sketch().clone()))
            }
        }
    }

    /// The sketch panel's relief slider: the sketch world at `relief_m`; returns the settings
    /// for the overlay.
    pub fn set_relief(&mut self, relief_m: f64) -> ShareState {
        let s = ShareState { relief_m, ..self.app.share_state() };
        self.app.apply_settings(s.clone());
        s
    }

    /// The sketch panel's extent slider: the sketch `extent_m` metres across (its terrain is
    /// made again for it), with the relief that fits it
    /// ([`crate::world::sketched::default_relief_m`]) unless the user chose another, and the
    /// camera where it shows the whole sketch; returns the settings for the overlay.
    pub fn set_extent(&mut self, extent_m: f64) -> ShareState {
        let now = self.app.share_state();
        let extent_m = crate::world::sketched::clamp_extent_m(extent_m);
        let default_relief = crate::world::sketched::default_relief_m;
        let relief_m = if now.relief_m == default_relief(now.extent_m) { default_relief(extent_m) } else { now.relief_m };
        let s = ShareState { extent_m, relief_m, ..now };
        self.app.apply_settings(s.clone());
        self.app.frame_sketch();
        self.app.share_state()
    }
}
