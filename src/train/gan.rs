//! What the project's GAN trainings share: the PatchGAN discriminator, least-squares
//! adversarial losses, Adam as pix2pix sets it, and checkpoint files.

use std::path::Path;

use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::store::{BurnpackStore, ModuleSnapshot};
use burn::tensor::activation::leaky_relu;
use burn::tensor::{Device, Tensor};

/// A PatchGAN discriminator: a window of heights and a condition (2 channels unless made with
/// [`Disc::with_inputs`]) → logits at 1/8 of
/// its size, three stride-2 3×3 convolutions with leaky ReLU and a 3×3 head. Training only.
#[derive(Module, Debug)]
pub struct Disc {
    convs: Vec<Conv2d>,
    head: Conv2d,
}

impl Disc {
    /// A freshly initialised discriminator of 2-channel windows on `device`.
    pub fn new(device: &Device) -> Self {
        Self::with_inputs(2, device)
    }

    /// A freshly initialised discriminator of `channels`-channel windows (heights first, then
    /// the condition) on `device`.
    pub fn with_inputs(channels: usize, device: &Device) -> Self {
        let widths = [channels, 32, 64, 128];
        let convs =
            widths.windows(2).map(|w| Conv2dConfig::new([w[0], w[1]], [3, 3]).with_stride([2, 2]).with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1)).init(device)).collect();
        Self { convs, head: Conv2dConfig::new([128, 1], [3, 3]).with_padding(PaddingConfig2d::Same).init(device) }
    }

    /// Logits [B, 1, H/8, W/8] for windows `x` [B, 2, H, W].
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut h = x;
        for c in &self.convs {
            h = leaky_relu(c.forward(h), 0.2);
        }
        self.head.forward(h)
    }

    /// The logits that judge `region`: those whose 8 px cell lies inside the square
    /// `region = (first px, size px)` of the window (all of them for `None`). A window whose
    /// real border surrounds a generated centre is judged on the centre only: the border's
    /// logits see the same pixels for real and fake and would only teach "0.5".
    fn judge(&self, x: Tensor<4>, region: Option<(usize, usize)>) -> Tensor<4> {
        let logits = self.forward(x);
        match region {
            None => logits,
            Some((first, size)) => {
                let (a, n) = (first / DISC_STRIDE, size.div_ceil(DISC_STRIDE).max(1));
                logits.narrow(2, a, n).narrow(3, a, n)
            }
        }
    }
}

/// Pixels per discriminator logit (three stride-2 convolutions).
pub const DISC_STRIDE: usize = 8;

/// Adam with β = (0.5, 0.999), as pix2pix trains both networks.
pub fn adam() -> ModuleOptimizer {
    AdamConfig::new().with_beta_1(0.5).with_beta_2(0.999).init()
}

/// One discriminator step (least squares: real → 1, fake → 0) at learning rate `lr`, judged on
/// `region` (see [`Disc`]); returns its loss. `fake` must be detached from the generator.
pub fn disc_step(d: &mut Disc, opt: &mut ModuleOptimizer, lr: f64, real: Tensor<4>, fake: Tensor<4>, region: Option<(usize, usize)>) -> f64 {
    let loss = ((d.judge(real, region) - 1.0).powf_scalar(2.0).mean() + d.judge(fake, region).powf_scalar(2.0).mean()) * 0.5;
    let value = loss.clone().into_scalar::<f32>() as f64;
    let gp = GradientsParams::from_grads(loss.backward(), d);
    *d = opt.step(lr, d.clone(), gp);
    value
}

/// The generator's least-squares adversarial term for its outputs `fake` (fake → 1), judged on
/// `region`.
pub fn gen_adversarial(d: &Disc, fake: Tensor<4>, region: Option<(usize, usize)>) -> Tensor<1> {
    (d.judge(fake, region) - 1.0).powf_scalar(2.0).mean()
}

/// Saves a run's checkpoint in `dir`: the generator as `gen_file`, and `{prefix}_disc.bpk`,
/// `{prefix}_adam.bin`, `{prefix}_disc_adam.bin` (the optimisers' moments) and
/// `{prefix}_state.json` (`state`).
#[allow(clippy::too_many_arguments)]
pub fn save_run<G: ModuleSnapshot>(
    dir: &Path,
    prefix: &str,
    gen_file: &str,
    g: &G,
    d: &Disc,
    og: &ModuleOptimizer,
    od: &ModuleOptimizer,
    state: &serde_json::Value,
) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    save(g, &dir.join(gen_file))?;
    save(d, &dir.join(format!("{prefix}_disc.bpk")))?;
    for (opt, file) in [(og, format!("{prefix}_adam.bin")), (od, format!("{prefix}_disc_adam.bin"))] {
        opt.save(dir.join(&file)).map_err(|e| format!("{file}: {e:?}"))?;
    }
    let file = format!("{prefix}_state.json");
    std::fs::write(dir.join(&file), serde_json::to_string_pretty(state).expect("json")).map_err(|e| format!("{file}: {e}"))
}

/// Loads what [`save_run`] saved into `g` and `d`; returns both optimisers (fresh where a
/// checkpoint was kept without its optimiser files) and the state.
pub fn load_run<G: ModuleSnapshot>(dir: &Path, prefix: &str, gen_file: &str, g: &mut G, d: &mut Disc) -> Result<(ModuleOptimizer, ModuleOptimizer, serde_json::Value), String> {
    load_into(g, &dir.join(gen_file))?;
    load_into(d, &dir.join(format!("{prefix}_disc.bpk")))?;
    // A checkpoint kept without its optimiser state (e.g. committed between sessions: the
    // moments are twice the weights' size) resumes with fresh moments.
    let load = |file: String| match dir.join(&file) {
        p if !p.exists() => {
            eprintln!("{}: not there, that optimiser starts afresh", p.display());
            Ok(adam())
        }
        p => adam().load(p).map_err(|e| format!("{file}: {e:?}")),
    };
    let (og, od) = (load(format!("{prefix}_adam.bin"))?, load(format!("{prefix}_disc_adam.bin"))?);
    Ok((og, od, read_state(dir, prefix)?))
}

/// The settings and progress a run saved in `dir` (`{prefix}_state.json`).
pub fn read_state(dir: &Path, prefix: &str) -> Result<serde_json::Value, String> {
    let file = format!("{prefix}_state.json");
    let text = std::fs::read_to_string(dir.join(&file)).map_err(|e| format!("{}: {e}", dir.join(&file).display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{file}: {e}"))
}

/// Loads a module's weights from a burnpack file; missing tensors are an error.
pub fn load_into<M: ModuleSnapshot>(m: &mut M, path: &Path) -> Result<(), String> {
    let mut store = BurnpackStore::from_file(path);
    let r = m.load_from(&mut store).map_err(|e| format!("{}: {e:?}", path.display()))?;
    if !r.missing.is_empty() {
        return Err(format!("{}: missing tensors {:?}", path.display(), r.missing));
    }
    Ok(())
}

/// Saves a module's weights to a burnpack file (overwriting it).
pub fn save<M: ModuleSnapshot>(m: &M, path: &Path) -> Result<(), String> {
    let mut store = BurnpackStore::from_file(path).overwrite(true);
    m.save_into(&mut store).map_err(|e| format!("saving {}: {e:?}", path.display()))
}
