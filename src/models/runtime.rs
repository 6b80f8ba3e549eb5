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
}

/// Why the models run on the CPU.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CpuReason {
    /// The WebGPU adapter is a software rasteriser (SwiftShader, llvmpipe): the CPU kernels are
    /// faster than a CPU-emulated GPU.
    SoftwareAdapter,
    /// The user asked for it (`?tem=cpu`).
    Asked,
    /// WebGPU compute failed its self-check or is missing (the message says how).
    NoGpuCompute(String),
}

/// The backend the models run on.
#[derive(Clone, Debug, PartialEq, Eq)]
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
            TemChoice::Auto | TemChoice::Off if software_adapter => Backend::Cpu(CpuReason::SoftwareAdapter),
            TemChoice::Auto | TemChoice::Off => Backend::Gpu,
        },
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
    }
}
