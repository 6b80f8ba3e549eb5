//! Where the models run in the page: the choice between the shared WebGPU device and the CPU
//! kernels ([`crate::models::cpu`]), and why. Pure policy, so it is tested natively; the browser shell only reports
//! what it found (adapter kind, self-check result) and acts on the answer.

/// Where the page runs the TEM, from `?tem=`: the adapter decides (`Auto`), or the user asks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TemChoice {
    /// WebGPU on a hardware adapter, the CPU on a software one.
    #[default]
    Auto,
    /// WebGPU even on a software adapter (`?tem=gpu`).
    Gpu,
    /// The CPU backend even with WebGPU (`?tem=cpu`).
    Cpu,
    /// Learned detail starts switched off (`?tem=off`).
    Off,
    /// As [`TemChoice::Auto`], and the start-up probe ([`probe_wanted`]) times the GPU against
    /// the CPU worker even on a software adapter (`?tem=probe`).
    Probe,
}

/// Why the models run on the CPU.
#[derive(Clone, Debug, PartialEq)]
pub enum CpuReason {
    /// The WebGPU adapter is a software rasteriser (SwiftShader, llvmpipe): the CPU kernels are
    /// faster than a CPU-emulated GPU.
    SoftwareAdapter,
    /// The user asked for it (`?tem=cpu`).
    Asked,
    /// WebGPU compute failed its self-check or is missing (the message says how).
    NoGpuCompute(String),
    /// The start-up probe found the CPU worker faster than the GPU.
    Faster(Timings),
}

/// What the start-up probe measured: the median milliseconds one TEM quad (level 0, the
/// probe's window) took on each backend, as its runner timed it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Timings {
    /// burn on the WebGPU device, readback included (ms).
    pub gpu_ms: f64,
    /// The CPU kernels in the worker (ms).
    pub cpu_ms: f64,
}

impl Timings {
    /// The overlay's words, for runs of `unit`: "WebGPU 3.1 ms, CPU 41.0 ms a quad".
    pub fn label(&self, unit: &str) -> String {
        format!("WebGPU {:.1} ms, CPU {:.1} ms a {unit}", self.gpu_ms, self.cpu_ms)
    }
}

/// The backend the models run on.
#[derive(Clone, Debug, PartialEq)]
pub enum Backend {
    /// burn's wgpu backend on the renderer's WebGPU device.
    Gpu,
    /// The CPU kernels ([`crate::models::cpu`]), and why.
    Cpu(CpuReason),
}

impl Backend {
    /// The overlay's name for it ("WebGPU", "CPU (software WebGPU adapter)", …).
    pub fn label(&self) -> String {
        match self {
            Backend::Gpu => "WebGPU".into(),
            Backend::Cpu(CpuReason::SoftwareAdapter) => "CPU (software WebGPU adapter)".into(),
            Backend::Cpu(CpuReason::Asked) => "CPU (asked for by ?tem=cpu)".into(),
            Backend::Cpu(CpuReason::NoGpuCompute(_)) => "CPU (no WebGPU compute)".into(),
            Backend::Cpu(CpuReason::Faster(t)) => format!("CPU (faster: {})", t.label("quad")),
        }
    }

    /// Whether this is the GPU.
    pub fn is_gpu(&self) -> bool {
        matches!(self, Backend::Gpu)
    }
}

/// Chooses the backend: the GPU when its self-check passed (`gpu` is `Ok`) and either the
/// user asked for it or the adapter is a hardware one not overridden by `?tem=cpu`; else the
/// CPU with the reason. `Off` and `Auto` choose alike (off only starts with detail hidden).
pub fn choose(choice: TemChoice, gpu: Result<(), String>, software_adapter: bool) -> Backend {
    match gpu {
        Err(e) => Backend::Cpu(CpuReason::NoGpuCompute(e)),
        Ok(()) => match choice {
            TemChoice::Gpu => Backend::Gpu,
            TemChoice::Cpu => Backend::Cpu(CpuReason::Asked),
            TemChoice::Auto | TemChoice::Off | TemChoice::Probe if software_adapter => Backend::Cpu(CpuReason::SoftwareAdapter),
            TemChoice::Auto | TemChoice::Off | TemChoice::Probe => Backend::Gpu,
        },
    }
}

/// Whether the page times the TEM on both backends once its first view is complete
/// ([`choose_measured`]): only where the choice is the page's (not `?tem=gpu` / `?tem=cpu`),
/// the GPU passed its self-check and the CPU worker runs. On a software adapter only when asked
/// (`?tem=probe`): there the "GPU" is an emulation on the very cores the worker uses, so it
/// cannot beat the kernels it emulates, and loading the TEM into it costs seconds of those
/// cores (measured on SwiftShader: see the e2e probe test).
pub fn probe_wanted(choice: TemChoice, gpu_ok: bool, worker_ok: bool, software_adapter: bool) -> bool {
    gpu_ok && worker_ok && matches!((choice, software_adapter), (TemChoice::Auto | TemChoice::Off, false) | (TemChoice::Probe, _))
}

/// The backend from the probe's timings: the faster of the two, the GPU on a tie. A GPU
/// whose self-check failed, or a backend the user asked for, wins over any timing
/// ([`choose`]).
pub fn choose_measured(choice: TemChoice, gpu: Result<(), String>, software_adapter: bool, timings: Timings) -> Backend {
    match (choose(choice, gpu, software_adapter), choice) {
        (b @ Backend::Cpu(CpuReason::NoGpuCompute(_) | CpuReason::Asked), _) | (b, TemChoice::Gpu) => b,
        _ if timings.cpu_ms < timings.gpu_ms => Backend::Cpu(CpuReason::Faster(timings)),
        _ => Backend::Gpu,
    }
}

/// How long the CPU worker rests per millisecond it worked on a learned tile or a TEM window
/// when the page draws on a software adapter: 2.0 keeps it to a third of a core, so the
/// rasteriser, which draws on the same 2 cores, keeps most of them while tiles are made.
/// Measured over the e2e learned flight (paced frames, SwiftShader, 2 cores), worst frame /
/// median: no rest 2.5–2.75, a rest of 1.0 2.0–2.5, 2.0 1.73–2.22 (median of 5 runs 1.84).
/// Tiles take three times as long from request to reply; their compute time is unchanged.
pub const SOFTWARE_WORKER_REST_PER_WORK: f64 = 2.0;

/// The worker's rest per millisecond of work: [`SOFTWARE_WORKER_REST_PER_WORK`] beside a
/// software adapter once the world on screen is complete (`view_complete`: smooth frames while
/// flying); none while the first picture of a world is still being made (a person waits for
/// it), nor beside a hardware GPU, which does not share the CPU's cores.
pub fn worker_rest_per_work(software_adapter: bool, view_complete: bool) -> f64 {
    if software_adapter && view_complete { SOFTWARE_WORKER_REST_PER_WORK } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Beside a software adapter, once the view is complete, the worker rests
    /// [`SOFTWARE_WORKER_REST_PER_WORK`] (at least as long as it worked); before that, and
    /// beside a GPU, not at all.
    #[test]
    fn the_worker_rests_only_beside_a_software_adapter_after_the_first_picture() {
        assert_eq!(worker_rest_per_work(true, true), SOFTWARE_WORKER_REST_PER_WORK);
        const { assert!(SOFTWARE_WORKER_REST_PER_WORK >= 1.0) };
        assert_eq!(worker_rest_per_work(true, false), 0.0);
        assert_eq!(worker_rest_per_work(false, true), 0.0);
        assert_eq!(worker_rest_per_work(false, false), 0.0);
    }

    /// Every combination of choice, self-check and adapter kind gives the documented backend.
    #[test]
    fn the_backend_follows_choice_self_check_and_adapter() {
        use TemChoice::*;
        let ok = || Ok(());
        assert_eq!(choose(Auto, ok(), false), Backend::Gpu);
        assert_eq!(choose(Off, ok(), false), Backend::Gpu);
        assert_eq!(choose(Auto, ok(), true), Backend::Cpu(CpuReason::SoftwareAdapter));
        assert_eq!(choose(Gpu, ok(), true), Backend::Gpu);
        assert_eq!(choose(Cpu, ok(), false), Backend::Cpu(CpuReason::Asked));
        for c in [Auto, Gpu, Cpu, Off] {
            let b = choose(c, Err("device lost".into()), false);
            assert_eq!(b, Backend::Cpu(CpuReason::NoGpuCompute("device lost".into())));
            assert_eq!(b.label(), "CPU (no WebGPU compute)");
        }
        assert_eq!(choose(Auto, ok(), true).label(), "CPU (software WebGPU adapter)");
        assert!(Backend::Gpu.is_gpu() && !choose(Cpu, ok(), false).is_gpu());
        assert_eq!(choose(Probe, ok(), true), Backend::Cpu(CpuReason::SoftwareAdapter));
        assert_eq!(choose(Probe, ok(), false), Backend::Gpu);
    }

    /// The probe runs where the page chooses and both backends work (on a software adapter
    /// only with `?tem=probe`); its timings pick the faster backend unless the user chose one
    /// or the GPU failed its self-check.
    #[test]
    fn the_probe_runs_where_the_page_chooses_and_the_faster_backend_wins() {
        use TemChoice::*;
        assert!(probe_wanted(Auto, true, true, false) && probe_wanted(Off, true, true, false));
        assert!(!probe_wanted(Auto, true, true, true) && probe_wanted(Probe, true, true, true));
        assert!(!probe_wanted(Gpu, true, true, false) && !probe_wanted(Cpu, true, true, false));
        assert!(!probe_wanted(Auto, false, true, false) && !probe_wanted(Auto, true, false, false) && !probe_wanted(Probe, false, true, true));
        let slow_gpu = Timings { gpu_ms: 40.0, cpu_ms: 12.5 };
        let fast_gpu = Timings { gpu_ms: 3.0, cpu_ms: 12.5 };
        assert_eq!(choose_measured(Auto, Ok(()), false, slow_gpu), Backend::Cpu(CpuReason::Faster(slow_gpu)));
        assert_eq!(choose_measured(Auto, Ok(()), false, fast_gpu), Backend::Gpu);
        assert_eq!(choose_measured(Probe, Ok(()), true, fast_gpu), Backend::Gpu);
        assert_eq!(choose_measured(Probe, Ok(()), true, slow_gpu).label(), "CPU (faster: WebGPU 40.0 ms, CPU 12.5 ms a quad)");
        assert_eq!(choose_measured(Auto, Ok(()), false, Timings { gpu_ms: 5.0, cpu_ms: 5.0 }), Backend::Gpu);
        assert_eq!(choose_measured(Gpu, Ok(()), false, slow_gpu), Backend::Gpu);
        assert_eq!(choose_measured(Cpu, Ok(()), false, fast_gpu), Backend::Cpu(CpuReason::Asked));
        assert!(matches!(choose_measured(Auto, Err("lost".into()), false, fast_gpu), Backend::Cpu(CpuReason::NoGpuCompute(_))));
    }
}
