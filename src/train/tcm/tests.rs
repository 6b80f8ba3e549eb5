//! Tests of the module.

use super::*;
use crate::models::grow::GrowCpu;
use crate::models::tcm::TcmCpu;
use crate::train::grow::{self, GrowRun};

fn synthetic(w: usize, h: usize, spacing: f64) -> Dem {
    let f = |x: f32, y: f32| (x * 0.031).sin() * 140.0 + (y * 0.047 + x * 0.011).cos() * 95.0 + ((x * 0.17).sin() * (y * 0.13).cos()) * 16.0 + 900.0;
    Dem { id: format!("synthetic_{spacing}m"), hf: Heightfield::new(w, h, spacing, (0..w * h).map(|k| f((k % w) as f32, (k / w) as f32)).collect()) }
}

/// One step of both networks on synthetic DEMs, a checkpoint, a resumed second step:
/// finite losses, the step count carried over (also from a checkpoint without its
/// optimiser files), and the saved weight files read by the CPU kernels.
#[test]
fn smoke_training_resumes_from_its_checkpoint() {
    let dems = vec![synthetic(500, 200, 100.0), synthetic(720, 230, 32.0)];
    let (coarse, fine) = (grids(&dems), grow::grids(&dems));
    assert_eq!((coarse.len(), fine.len()), (1, 1), "the 100 m DEM serves the TCM (the 32 m one is too small at 128 m), the 32 m one the ×4 step");
    let device = Device::flex().autodiff();
    let cfg = TcmConfig { batch: 1, ..Default::default() };
    let dir = std::env::temp_dir().join(format!("terrain-tcm-smoke-{}", std::process::id()));
    let mut run = start_run(cfg.clone(), &device, None, None).unwrap();
    let mut up = GrowRun::start(1, 1.0, &device, None).unwrap();
    run.step(&coarse).unwrap();
    up.step(&fine, 1).unwrap();
    run.save(&dir).unwrap();
    up.save(&dir).unwrap();
    let mut run = start_run(cfg, &device, Some(&dir), None).unwrap();
    let mut up = GrowRun::start(1, 1.0, &device, Some(&dir)).unwrap();
    assert_eq!((run.progress.step, up.progress.step), (1, 1));
    run.step(&coarse).unwrap();
    up.step(&fine, 1).unwrap();
    for p in [&run.progress, &up.progress] {
        assert_eq!(p.step, 2);
        assert!(p.l1.is_finite() && p.adv.is_finite() && p.disc.is_finite(), "{p:?}");
        assert!(p.l1 > 0.0 && p.disc > 0.0);
    }
    // Kept without its optimiser files (as between sessions), the run still resumes.
    run.save(&dir).unwrap();
    for f in ["tcm_adam.bin", "tcm_disc_adam.bin"] {
        std::fs::remove_file(dir.join(f)).unwrap();
    }
    assert_eq!(start_run(TcmConfig::default(), &device, Some(&dir), None).unwrap().progress.step, 2);
    // The saved generator is the trained one: the same output to the bit on a training
    // window's input, and not a fresh generator's.
    let input = run.batch(&coarse).unwrap().inputs[..IN_CHANNELS * CONTEXT_PX * CONTEXT_PX].to_vec();
    let out = |m: &TcmCpu| m.forward(&input, &mut Default::default(), 1);
    let saved = out(&TcmCpu::from_burnpack(&std::fs::read(dir.join(GEN_FILE)).unwrap()).unwrap());
    assert_eq!(saved, out(&TcmCpu::from_model(&run.g).unwrap()), "the saved TCM is not the trained one");
    assert_ne!(saved, out(&TcmCpu::from_model(&start_run(TcmConfig::default(), &device, None, None).unwrap().g).unwrap()));
    assert!(GrowCpu::from_burnpack(&std::fs::read(dir.join(grow::GROW_FILE)).unwrap()).is_ok());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Each trainer learns: on one fixed batch of two windows with the adversary off, twelve steps
/// lower the batch's L1 term to under 60 % of the first step's for the TCM (from the shipped
/// weights at learning rate 1e-4: from a random start its L1 sits near 0.105 for tens of
/// steps while it learns the tile's mean, and larger rates make it jump) and to under 70 %
/// for its ×4 step (from a seeded random start at 1e-3).
#[test]
fn twelve_steps_on_one_fixed_batch_lower_the_l1_of_the_tcm_below_60_and_of_the_x4_step_below_70_percent() {
    let dems = vec![synthetic(500, 200, 100.0), synthetic(720, 230, 32.0)];
    let (coarse, fine) = (grids(&dems), grow::grids(&dems));
    let device = Device::flex().autodiff();
    let shipped = TcmCpu::from_burnpack(&std::fs::read(crate::repo_root().join("weights").join(crate::world::learned::TCM_FILE)).unwrap()).unwrap();
    let cfg = TcmConfig { batch: 2, adversarial: 0.0, lr: 1e-4, ..Default::default() };
    let mut run = start_run(cfg, &device, None, Some(&shipped)).unwrap();
    let batch = run.batch(&coarse).unwrap();
    let tcm: Vec<f64> = (0..12).map(|_| run.fit(&batch).unwrap()).collect();
    let mut up = GrowRun::start(2, 0.0, &device, None).unwrap();
    up.g = GrowCpu::randomized(3, 0.05).into_model(up.g.clone());
    up.lr = 1e-3;
    let batch = up.batch(&fine, 1).unwrap();
    let x4: Vec<f64> = (0..12).map(|_| up.fit(&batch).unwrap()).collect();
    eprintln!("fixed-batch L1: TCM {tcm:.4?}, ×4 {x4:.5?}");
    assert!(tcm[11] < 0.6 * tcm[0], "TCM L1 {tcm:?}");
    assert!(x4[11] < 0.7 * x4[0], "×4 step L1 {x4:?}");
}

/// The GPU path trains the TCM and its ×4 step like the CPU path: from one saved start (a
/// fresh CPU run's checkpoint), three steps of each network (L1, adversarial and
/// discriminator terms) on burn's wgpu backend (lavapipe here) and on its CPU backend give
/// running L1 losses within 1e-4 (units of the height scale; f32 with other summation
/// orders), and the steps change the TCM's by more than ten times the TCM's own gap between
/// the backends (the ×4 step's gap, ~2e-5 on some runs, is not the TCM's).
#[test]
fn gpu_and_cpu_backends_train_the_same_three_tcm_and_x4_steps() {
    use crate::train::Backend;
    let dems = vec![synthetic(500, 200, 100.0), synthetic(720, 230, 32.0)];
    let (coarse, fine) = (grids(&dems), grow::grids(&dems));
    let cfg = TcmConfig { batch: 2, ..Default::default() };
    let dir = std::env::temp_dir().join(format!("terrain-tcm-backends-{}", std::process::id()));
    let cpu = Backend::Cpu.device().unwrap();
    start_run(cfg.clone(), &cpu, None, None).unwrap().save(&dir).unwrap();
    GrowRun::start(2, 1.0, &cpu, None).unwrap().save(&dir).unwrap();
    let train = |backend: Backend| {
        let device = backend.device().unwrap();
        let mut run = start_run(cfg.clone(), &device, Some(&dir), None).unwrap();
        let mut up = GrowRun::start(2, 1.0, &device, Some(&dir)).unwrap();
        (0..3)
            .map(|_| {
                run.step(&coarse).unwrap();
                up.step(&fine, 1).unwrap();
                [run.progress.l1, up.progress.l1]
            })
            .collect::<Vec<[f64; 2]>>()
    };
    let (gpu, cpu) = (train(Backend::Gpu), train(Backend::Cpu));
    let gap = gpu.iter().flatten().zip(cpu.iter().flatten()).map(|(a, b)| (a - b).abs()).fold(0f64, f64::max);
    eprintln!("TCM, ×4 running L1: gpu {gpu:?}, cpu {cpu:?}, largest gap {gap:.2e}");
    assert!(gap < 1e-4, "losses differ by {gap}");
    // The TCM's running L1 moves by far more than the gap at some step (the ×4 step's, a
    // running mean of a smaller loss, by about 1e-5 in three steps; a running mean can come
    // back near where it started, so the largest move counts, not the last).
    let moved = cpu.iter().map(|l| (l[0] - cpu[0][0]).abs()).fold(0f64, f64::max);
    let tcm_gap = gpu.iter().zip(&cpu).map(|(a, b)| (a[0] - b[0]).abs()).fold(0f64, f64::max);
    assert!(moved > 10.0 * tcm_gap.max(1e-6), "the steps did not change the TCM's loss: {cpu:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The training's ruggedness term measures what the world's ruggedness field means: on a
/// random window, ln relief of the centre equals [`tile_ruggedness`]'s centre value minus
/// ln(HEIGHT_SCALE_M / RUGGEDNESS_REF_M) to 1e-4; the gap between a window and itself is 0,
/// and between a window and the same window twice as high is ln 2 (to 1e-4).
#[test]
fn ruggedness_term_is_the_log_relief_gap_of_the_centre_tiles() {
    let device = Device::flex();
    let mut rng = Rng(5);
    let metres: Vec<f32> =
        (0..CONTEXT_PX * CONTEXT_PX).map(|p| 40.0 * ((p % 7) as f32 * 0.9).sin() + (p / CONTEXT_PX) as f32 * 3.0 + (rng.next_u64() % 1000) as f32 * 0.05).collect();
    let units: Vec<f32> = metres.iter().map(|h| h / HEIGHT_SCALE_M).collect();
    let w = tensor(units.clone(), [1, 1, CONTEXT_PX, CONTEXT_PX], &device);
    let ours = centre_log_relief(w.clone()).into_scalar::<f32>();
    let want = tile_ruggedness(&metres)[4] - (HEIGHT_SCALE_M / crate::models::tcm::RUGGEDNESS_REF_M).ln();
    assert!((ours - want).abs() < 1e-4, "{ours} vs {want}");
    assert!(log_relief_gap(w.clone(), w.clone()).into_scalar::<f32>().abs() < 1e-6);
    let gap = log_relief_gap(w.clone() * 2.0, w).into_scalar::<f32>();
    assert!((gap - 2f32.ln()).abs() < 1e-4, "{gap}");
}

/// The coarse term of a tile against itself is 0; against itself plus a bowl that is
/// −1 inside the central 16² and 0 elsewhere it is the mean |block-mean difference| over
/// the 4×4 blocks of 8²: the 4 central blocks differ by 1, so 4 / 16 = 0.25 (to 1e-6);
/// a detail that averages to zero in every block costs nothing.
#[test]
fn coarse_term_is_the_mean_gap_of_block_means() {
    let device = Device::flex();
    let t = TILE_PX;
    let base: Vec<f32> = (0..t * t).map(|p| ((p % t) as f32 * 0.3).sin() + (p / t) as f32 * 0.01).collect();
    let a = tensor(base.clone(), [1, 1, t, t], &device);
    assert_eq!(coarse_gap(a.clone(), a.clone()).into_scalar::<f32>(), 0.0);
    let bowl: Vec<f32> = (0..t * t).map(|p| base[p] - if (8..24).contains(&(p % t)) && (8..24).contains(&(p / t)) { 1.0 } else { 0.0 }).collect();
    let gap = coarse_gap(tensor(bowl, [1, 1, t, t], &device), a.clone()).into_scalar::<f32>();
    assert!((gap - 0.25).abs() < 1e-6, "{gap}");
    let checker: Vec<f32> = (0..t * t).map(|p| base[p] + if (p % t + p / t).is_multiple_of(2) { 0.5 } else { -0.5 }).collect();
    assert!(coarse_gap(tensor(checker, [1, 1, t, t], &device), a).into_scalar::<f32>() < 1e-6);
}

/// Windows with errors 1 and 3: equal weights give the plain mean 2; weights 0.25 and 1
/// give (0.25·1 + 3) / 1.25 = 2.6; weight 0 on the first leaves the second's 3.
#[test]
fn weighted_l1_weights_each_sample_and_divides_by_the_weights_sum() {
    let device = Device::flex();
    let n = TILE_PX * TILE_PX;
    let made = tensor([vec![1.0; n], vec![-3.0; n]].concat(), [2, 1, TILE_PX, TILE_PX], &device);
    let real = tensor(vec![0.0; 2 * n], [2, 1, TILE_PX, TILE_PX], &device);
    for (w, want) in [([1.0, 1.0], 2.0), ([0.25, 1.0], 2.6), ([0.0, 1.0], 3.0)] {
        let weights = [vec![w[0]; n], vec![w[1]; n]].concat();
        let got = weighted_l1(made.clone(), real.clone(), weights).into_scalar::<f32>();
        assert!((got - want).abs() < 1e-5, "{w:?}: {got}");
    }
}

/// Phase 0 (no neighbour) weighs L1 by `free` everywhere; with only the −x neighbour
/// given and reach 4, the first column (0.5 samples from it) weighs
/// 0.1 + 0.9·e^(−1/8) ≈ 0.894 and the last (31.5 samples away) 0.1 + 0.9·e^(−7.875)
/// ≈ 0.1003; reach 0 weighs 1 everywhere.
#[test]
fn l1_weight_map_is_free_far_from_the_given_neighbours_and_full_beside_them() {
    assert!(l1_weight_map(&[false; 9], 0.1, 4.0).iter().all(|&w| w == 0.1));
    let mut left = [false; 9];
    left[3] = true;
    let w = l1_weight_map(&left, 0.1, 4.0);
    let want_first = 0.1 + 0.9 * (-0.125f32).exp();
    let want_last = 0.1 + 0.9 * (-7.875f32).exp();
    for row in [0, 17, TILE_PX - 1] {
        assert!((w[row * TILE_PX] - want_first).abs() < 1e-5, "{}", w[row * TILE_PX]);
        assert!((w[row * TILE_PX + TILE_PX - 1] - want_last).abs() < 1e-5);
    }
    assert!(l1_weight_map(&left, 0.1, 0.0).iter().all(|&w| w == 1.0));
}

/// A made tile 5 units below the plane its given −x neighbour continues is moved up by 5
/// at its −x edge (the join's membrane fixes that edge) and not at all in phase 0; the
/// offsets are the world's join, applied to the tile beside the real window.
#[test]
fn joined_offsets_are_what_the_worlds_join_adds() {
    let c = CONTEXT_PX;
    let real: Vec<f32> = (0..c * c).map(|p| (p % c) as f32 * 0.01).collect();
    let made: Vec<f32> = (0..TILE_PX * TILE_PX).map(|p| (TILE_PX + p % TILE_PX) as f32 * 0.01 - 5.0).collect();
    let mut left = [false; 9];
    left[3] = true;
    let off = joined_offsets(&[made.clone(), made.clone()].concat(), &[real.clone(), real].concat(), &[left, [false; 9]]);
    for row in [0, 16, TILE_PX - 1] {
        assert!((off[row * TILE_PX] - 5.0).abs() < 1e-4, "{}", off[row * TILE_PX]);
    }
    assert!(off[TILE_PX * TILE_PX..].iter().all(|&o| o == 0.0));
    let mut want = made.clone();
    let nb = tile_of(&(0..c * c).map(|p| (p % c) as f32 * 0.01).collect::<Vec<_>>(), 3);
    seam::join_edges(&mut want, TILE_PX, [Some(&nb), None, None, None]);
    for p in 0..TILE_PX * TILE_PX {
        assert!((made[p] + off[p] - want[p]).abs() < 1e-5);
    }
}

/// The dome term: 0 for made = real; a made batch whose phase-0 tile is the real one plus
/// a paraboloid of dome height h (and phase-2 tile plus a plane) scores h · ½ (phase 0's
/// share of the batch), the plane adding nothing; a bowl and a dome of the same size in
/// one phase cancel.
#[test]
fn dome_gap_is_the_phase_mean_dome_error_weighted_by_share() {
    let device = Device::flex();
    let n = TILE_PX;
    let c = (n as f32 - 1.0) / 2.0;
    let real: Vec<f32> = (0..n * n).map(|p| ((p % n) as f32 * 0.37).sin()).collect();
    let bump: Vec<f32> = (0..n * n)
        .map(|p| {
            let (x, y) = ((p % n) as f32 - c, (p / n) as f32 - c);
            100.0 - x * x - y * y
        })
        .collect();
    let h = dome_height(&bump) as f32;
    let plane: Vec<f32> = (0..n * n).map(|p| (p % n) as f32 * 0.5 + (p / n) as f32).collect();
    let both = |a: &[f32], b: &[f32]| tensor([a.to_vec(), b.to_vec()].concat(), [2, 1, n, n], &device);
    let r = both(&real, &real);
    assert!(dome_gap(r.clone(), r.clone(), &[0, 2]).into_scalar::<f32>().abs() < 1e-5);
    let domed: Vec<f32> = real.iter().zip(&bump).map(|(a, b)| a + b).collect();
    let tilted: Vec<f32> = real.iter().zip(&plane).map(|(a, b)| a + b).collect();
    let got = dome_gap(both(&domed, &tilted), r.clone(), &[0, 2]).into_scalar::<f32>();
    assert!((got - h / 2.0).abs() < 1e-3 * h, "{got} vs {}", h / 2.0);
    let bowl: Vec<f32> = real.iter().zip(&bump).map(|(a, b)| a - b).collect();
    assert!(dome_gap(both(&domed, &bowl), r, &[1, 1]).into_scalar::<f32>().abs() < 1e-3);
}

/// The plane h = 0.01·x + 0.02·y has slopes 0.05 and 0.1 (× the gain 5) everywhere but
/// in the last column (x) and row (y), which are 0; the heights pass unchanged.
#[test]
fn with_slopes_appends_the_scaled_forward_differences() {
    let device = Device::flex();
    let n = 8;
    let h: Vec<f32> = (0..n * n).map(|p| 0.01 * (p % n) as f32 + 0.02 * (p / n) as f32).collect();
    let out = with_slopes(tensor(h.clone(), [1, 1, n, n], &device)).into_data().try_to_vec::<f32>().unwrap();
    assert_eq!(out.len(), 3 * n * n);
    for p in 0..n * n {
        let (x, y) = (p % n, p / n);
        assert!((out[p] - h[p]).abs() < 1e-7);
        assert!((out[n * n + p] - if x + 1 < n { 0.05 } else { 0.0 }).abs() < 1e-5, "dx at {x},{y}");
        assert!((out[2 * n * n + p] - if y + 1 < n { 0.1 } else { 0.0 }).abs() < 1e-5, "dy at {x},{y}");
    }
}

/// The position term is 0 (to 1e-4) for tiles as rough at every position (a checkerboard
/// of ±1: every second difference is ±4), and for a ridge one sample wide along column 10
/// (|second difference| 2 there, 1 beside it, 0 elsewhere) the mean |ratio − 1| of that
/// 60-value profile.
#[test]
fn position_gap_is_zero_for_uniform_roughness_and_the_profiles_deviation_otherwise() {
    let n = TILE_PX;
    let dev = Device::flex();
    let checker: Vec<f32> = (0..2 * n * n).map(|p| if (p % n + p / n).is_multiple_of(2) { 1.0 } else { -1.0 }).collect();
    let got = position_gap(tensor(checker, [2, 1, n, n], &dev)).into_scalar::<f32>();
    assert!(got.abs() < 1e-4, "{got}");
    // A ridge along one column c: |d2x| is 2 at c, 1 at c ± 1 and 0 elsewhere; no d2y.
    let c = 10;
    let ridge: Vec<f32> = (0..n * n).map(|p| if p % n == c { 1.0 } else { 0.0 }).collect();
    let got = position_gap(tensor(ridge, [1, 1, n, n], &dev)).into_scalar::<f32>() as f64;
    // The profile: 60 values, of which x has 2, 1, 1 at three columns; mean 4/60.
    let m = 4.0 / 60.0;
    let want = ((2.0 / m - 1.0) + 2.0 * (1.0 / m - 1.0) + 57.0) / 60.0;
    assert!((got - want).abs() < 1e-3 * want, "{got} vs {want}");
}

/// A tilted plane has a dome height of 0 (to 1e-9); the paraboloid 100 − r² (r in
/// samples from the centre) has the interior-minus-edge mean of its plane residual,
/// counted here sample by sample (to 1e-6), positive; its negative is a bowl.
#[test]
fn dome_height_is_zero_for_a_plane_and_signs_domes_and_bowls() {
    let n = TILE_PX;
    let c = (n as f64 - 1.0) / 2.0;
    let plane: Vec<f32> = (0..n * n).map(|p| 3.0 + 0.5 * (p % n) as f32 - 0.25 * (p / n) as f32).collect();
    assert!(dome_height(&plane).abs() < 1e-9);
    let r2 = |p: usize| ((p % n) as f64 - c).powi(2) + ((p / n) as f64 - c).powi(2);
    let dome: Vec<f32> = (0..n * n).map(|p| (100.0 - r2(p)) as f32).collect();
    let d = |p: usize| (p % n).min(n - 1 - p % n).min(p / n).min(n - 1 - p / n);
    let mean_of = |f: &dyn Fn(usize) -> bool| {
        let v: Vec<f64> = (0..n * n).filter(|&p| f(p)).map(|p| -r2(p)).collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    let want = mean_of(&|p| d(p) >= COARSE_BLOCK_PX) - mean_of(&|p| d(p) == 0);
    assert!(want > 100.0);
    assert!((dome_height(&dome) - want).abs() < 1e-6 * want, "{} vs {want}", dome_height(&dome));
    let bowl: Vec<f32> = dome.iter().map(|v| -v).collect();
    assert!((dome_height(&bowl) + want).abs() < 1e-6 * want);
}

/// The drainage term of a window whose centre tile holds a cone-shaped pit 0.2 deep on a
/// tilted plane is the pit's mean depth below its spill level over the centre (counted
/// here sample by sample from the known spill height, to 1e-6); its gradient lifts the
/// pit's samples (−1/1024 each) and is zero everywhere else; a tilted plane scores 0.
#[test]
fn drainage_term_is_the_mean_depth_of_the_centre_tiles_pits() {
    let device = Device::flex().autodiff();
    let n = CONTEXT_PX;
    let plane = |p: usize| (p % n) as f32 * 0.01;
    let (cx, cy) = (n / 2, n / 2);
    let pit = |p: usize| {
        let r = (((p % n) as f32 - cx as f32).powi(2) + ((p / n) as f32 - cy as f32).powi(2)).sqrt();
        (0.2 - 0.05 * r).max(0.0)
    };
    let h: Vec<f32> = (0..n * n).map(|p| plane(p) - pit(p)).collect();
    let flat = tensor((0..n * n).map(plane).collect(), [1, 1, n, n], &Device::flex());
    assert_eq!(depression_depth(flat).into_scalar::<f32>(), 0.0);
    // The pit spills over its rim on its low (west) side: at the first sample west of
    // the centre that the pit does not lower; the plane beyond drains.
    let spill = (0..cx).rev().map(|x| cy * n + x).find(|&p| pit(p) == 0.0).map(|p| h[p]).unwrap();
    let want: f64 = (0..n * n)
        .filter(|&p| (TILE_PX..2 * TILE_PX).contains(&(p % n)) && (TILE_PX..2 * TILE_PX).contains(&(p / n)))
        .filter(|&p| pit(p) > 0.0)
        .map(|p| (spill - h[p]).max(0.0) as f64)
        .sum::<f64>()
        / (TILE_PX * TILE_PX) as f64;
    let w = tensor(h.clone(), [1, 1, n, n], &device).require_grad();
    let d = depression_depth(w.clone());
    assert!((d.clone().into_scalar::<f32>() as f64 - want).abs() < 1e-6, "{} vs {want}", d.clone().into_scalar::<f32>());
    let grads = d.backward();
    let g: Vec<f32> = w.grad(&grads).unwrap().into_data().try_to_vec::<f32>().unwrap();
    for p in 0..n * n {
        let lifted = pit(p) > 0.0 && spill > h[p] && (TILE_PX..2 * TILE_PX).contains(&(p % n)) && (TILE_PX..2 * TILE_PX).contains(&(p / n));
        assert_eq!(g[p], if lifted { -1.0 / (TILE_PX * TILE_PX) as f32 } else { 0.0 }, "sample {p}");
    }
}

/// On terrain whose 4096 m tile means are all alike but whose 2048 m cells are not (a ripple
/// of one tile's period, ±300 m): in a sample with 6 macro cells a side, the macro channel
/// around each cell's centre is the field of the window's true cell means to within 3.5
/// jitter deviations (the jitter's bound), and with 3 cells it misses that field somewhere by
/// more than its own bound.
#[test]
fn six_cell_samples_carry_each_2048_m_cell_mean_where_three_cells_do_not() {
    let (w, h) = (400, 200);
    let ripple = |x: usize, y: usize| 1000.0 + 300.0 * (x as f32 * std::f32::consts::TAU / 32.0).sin() + 200.0 * (y as f32 * std::f32::consts::TAU / 32.0).cos();
    let dem = Dem { id: "ripple_128m".into(), hf: Heightfield::new(w, h, 128.0, (0..w * h).map(|k| ripple(k % w, k / w)).collect()) };
    let g = &grids(&[dem])[0];
    let n = CONTEXT_PX * CONTEXT_PX;
    // A field's mean over the four pixels around the centre of 2048 m cell `q`.
    let at_cell = |m: &[f32], q: usize| {
        let p = ((q / 6) * 16 + 8) * CONTEXT_PX + (q % 6) * 16 + 8;
        (m[p] + m[p - 1] + m[p - CONTEXT_PX] + m[p - CONTEXT_PX - 1]) / 4.0
    };
    let jitter_of = |heights: &[f32]| {
        let t = cell_means(heights, 3);
        let avg = t.iter().sum::<f32>() / 9.0;
        MACRO_JITTER_M + MACRO_JITTER_FRACTION * (t.iter().map(|m| (m - avg).powi(2)).sum::<f32>() / 9.0).sqrt()
    };
    let mut worst_three = 0f32;
    for seed in 0..8u64 {
        for (k, mut rng) in [(6, Rng(seed)), (3, Rng(seed))] {
            let s = sample(&g.hf, Split::Train, 1, k, &mut rng).unwrap();
            // Metres above the sample's level, like the macro channel.
            let heights: Vec<f32> = s.real.iter().map(|v| v * HEIGHT_SCALE_M).collect();
            let truth = macro_field_cells(&cell_means(&heights, 6), 6);
            let made: Vec<f32> = s.input[4 * n..5 * n].iter().map(|v| v * HEIGHT_SCALE_M).collect();
            let bound = 3.5 * jitter_of(&heights) + 0.5;
            for q in 0..36 {
                let miss = (at_cell(&made, q) - at_cell(&truth, q)).abs();
                if k == 6 {
                    assert!(miss < bound, "seed {seed}, cell {q}: the macro field misses the cell means' field by {miss} m (bound {bound} m)");
                } else {
                    worst_three = worst_three.max(miss - bound);
                }
            }
        }
    }
    assert!(worst_three > 0.0, "3 cells a side held the 2048 m cell means' field as closely");
}

/// The coherence term agrees with eval-tcm's measure: on windows at 128 m of parallel ridges
/// 3 km apart (turned off the grid) the centre's coherence is over 0.95 and on an egg-crate of
/// 2 km bumps under 0.2 (as `orientation_coherence` on 32 m windows of the same fields); the
/// gap between a window and itself is 0 (to 1e-6) and between the two fields over 0.75.
#[test]
fn coherence_term_is_zero_for_the_same_window_and_large_between_ridges_and_bumps() {
    let device = Device::flex();
    let tau = std::f32::consts::TAU;
    let field = |f: &dyn Fn(f32, f32) -> f32| -> Vec<f32> {
        (0..CONTEXT_PX * CONTEXT_PX).map(|p| f((p % CONTEXT_PX) as f32 * 128.0, (p / CONTEXT_PX) as f32 * 128.0) / HEIGHT_SCALE_M).collect()
    };
    let ridges = tensor(field(&|x, y| 300.0 * (tau * (0.8 * x + 0.6 * y) / 3000.0).sin()), [1, 1, CONTEXT_PX, CONTEXT_PX], &device);
    let bumps = tensor(field(&|x, y| 300.0 * (tau * x / 2000.0).sin() * (tau * y / 2000.0).sin()), [1, 1, CONTEXT_PX, CONTEXT_PX], &device);
    let (r, e) = (centre_coherence(ridges.clone()).into_scalar::<f32>(), centre_coherence(bumps.clone()).into_scalar::<f32>());
    assert!(r > 0.95 && e < 0.2, "ridges {r}, egg-crate {e}");
    assert!(coherence_gap(ridges.clone(), ridges.clone()).into_scalar::<f32>().abs() < 1e-6);
    let gap = coherence_gap(bumps, ridges).into_scalar::<f32>();
    assert!(gap > 0.75, "{gap}");
}

/// A training step with the coherence term on (and the adversary off) gives a finite,
/// positive L1 and moves the generator: its output on the batch's first input changes.
#[test]
fn a_step_with_the_coherence_term_trains_the_generator() {
    let dems = vec![synthetic(500, 200, 100.0)];
    let coarse = grids(&dems);
    let device = Device::flex().autodiff();
    let cfg = TcmConfig { batch: 1, adversarial: 0.0, coherence: 1.0, ..Default::default() };
    let mut run = start_run(cfg, &device, None, None).unwrap();
    let batch = run.batch(&coarse).unwrap();
    let input = batch.inputs[..IN_CHANNELS * CONTEXT_PX * CONTEXT_PX].to_vec();
    let before = TcmCpu::from_model(&run.g).unwrap().forward(&input, &mut Default::default(), 1);
    let l1 = run.fit(&batch).unwrap();
    assert!(l1.is_finite() && l1 > 0.0, "{l1}");
    assert_ne!(before, TcmCpu::from_model(&run.g).unwrap().forward(&input, &mut Default::default(), 1));
}
