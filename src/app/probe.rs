//! The start-up probes that pick where each model runs from measured timings. The TEM's: once
//! the page's first view is complete, the TEM is loaded on the backend it does not run on yet,
//! one probe quad (level 0, [`crate::models::tem::probe_input`]) is timed on the GPU and on the
//! CPU worker, one warm-up and [`TIMED_RUNS`] timed runs each, one at a time so neither slows
//! the other, and the faster backend runs the TEM from then on
//! ([`crate::models::runtime::choose_measured`]). The sketch generator's: once it has loaded on
//! both (the sketch world shown), the canvas's sketch is made on each, a warm-up and
//! [`SKETCH_TIMED_RUNS`] timed runs, and strokes go to the faster. Pure state: the page's core
//! posts the requests and hands back the runners' times.

use super::page::Target;
use crate::models::runtime::Timings;

/// Timed probe quads per backend, after one warm-up quad whose time is not counted.
pub const TIMED_RUNS: usize = 3;
/// Timed probe sketches per backend, after one warm-up sketch (a sketch is ~6× a quad's work).
pub const SKETCH_TIMED_RUNS: usize = 2;

/// Where the probe is.
#[derive(Clone, Debug, PartialEq)]
pub enum Probe {
    /// Not wanted here ([`crate::models::runtime::probe_wanted`]).
    Off,
    /// Waiting for the TEM to load and the first view to be complete.
    Waiting,
    /// The TEM is loading on the other backend.
    Loading,
    /// Probe quads: the runs still to make (in order) and the milliseconds each backend's runs
    /// took so far (warm-ups included).
    Timing {
        /// The backends of the runs still to make, next first.
        left: Vec<Target>,
        /// The GPU's runs so far (ms).
        gpu: Vec<f64>,
        /// The CPU worker's runs so far (ms).
        cpu: Vec<f64>,
    },
    /// Measured.
    Done(Timings),
    /// The probe failed (why); the first choice stays.
    Failed(String),
}

impl Probe {
    /// The timing stage of `timed` runs per backend after a warm-up each: the GPU's runs
    /// first, then the worker's.
    pub fn timing(timed: usize) -> Self {
        let left = std::iter::repeat_n(Target::Gpu, 1 + timed).chain(std::iter::repeat_n(Target::Worker, 1 + timed)).collect();
        Probe::Timing { left, gpu: Vec::new(), cpu: Vec::new() }
    }

    /// The backend of the next run, while timing.
    pub fn next(&self) -> Option<Target> {
        match self {
            Probe::Timing { left, .. } => left.first().copied(),
            _ => None,
        }
    }

    /// Records that a run on `target` took `ms`; after the last run the probe is
    /// [`Probe::Done`] with each backend's median timed run. A run that was not asked for
    /// (another stage, another backend) is ignored.
    pub fn record(&mut self, target: Target, ms: f64) {
        let Probe::Timing { left, gpu, cpu } = self else { return };
        if left.first() != Some(&target) {
            return;
        }
        left.remove(0);
        if target == Target::Gpu {
            gpu.push(ms)
        } else {
            cpu.push(ms)
        };
        if left.is_empty() {
            *self = Probe::Done(Timings { gpu_ms: median_after_warm_up(gpu), cpu_ms: median_after_warm_up(cpu) });
        }
    }

    /// The overlay's words for it, if it has something to say: `model` names the model
    /// ("TEM"), `unit` one run ("quad").
    pub fn label(&self, model: &str, unit: &str) -> Option<String> {
        match self {
            Probe::Off | Probe::Waiting => None,
            Probe::Loading | Probe::Timing { .. } => Some(format!("{model} probe: timing WebGPU against the CPU")),
            Probe::Done(t) => Some(format!("{model} probe: {}", t.label(unit))),
            Probe::Failed(why) => Some(format!("{model} probe failed ({why})")),
        }
    }
}

/// The median of `runs` without the first (the warm-up).
fn median_after_warm_up(runs: &[f64]) -> f64 {
    let mut timed = runs.get(1..).unwrap_or_default().to_vec();
    if timed.is_empty() {
        return f64::NAN;
    }
    timed.sort_by(f64::total_cmp);
    timed[timed.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The probe times the GPU's runs, then the worker's, drops each one's warm-up and keeps
    /// the median of the rest; a reply out of turn changes nothing.
    #[test]
    fn the_probe_keeps_each_backends_median_after_its_warm_up_and_ignores_replies_out_of_turn() {
        let mut p = Probe::timing(TIMED_RUNS);
        assert_eq!(p.next(), Some(Target::Gpu));
        p.record(Target::Worker, 1.0);
        assert_eq!(p, Probe::timing(TIMED_RUNS), "a worker reply while the GPU runs is ignored");
        for ms in [900.0, 30.0, 10.0, 20.0] {
            p.record(Target::Gpu, ms);
        }
        assert_eq!(p.next(), Some(Target::Worker));
        for ms in [50.0, 7.0, 5.0, 6.0] {
            p.record(Target::Worker, ms);
        }
        assert_eq!(p, Probe::Done(Timings { gpu_ms: 20.0, cpu_ms: 6.0 }));
        assert_eq!(p.next(), None);
        assert_eq!(p.label("TEM", "quad").unwrap(), "TEM probe: WebGPU 20.0 ms, CPU 6.0 ms a quad");
        assert_eq!(Probe::Waiting.label("TEM", "quad"), None);
        let mut s = Probe::timing(SKETCH_TIMED_RUNS);
        for (t, ms) in [(Target::Gpu, 99.0), (Target::Gpu, 4.0), (Target::Gpu, 2.0), (Target::Worker, 9.0), (Target::Worker, 3.0), (Target::Worker, 5.0)] {
            s.record(t, ms);
        }
        assert_eq!(s, Probe::Done(Timings { gpu_ms: 4.0, cpu_ms: 5.0 }), "of two timed runs the slower counts");
    }
}
