//! `terrain tile-bench`: how long the learned world's two networks take per phase batch, on the
//! project's CPU kernels or on burn's wgpu backend (Vulkan natively: a GPU's driver, or Mesa's
//! lavapipe), so the CPU worker and a GPU can be compared on the same inputs.

#[allow(unused_imports)]
use crate::*;

/// One model's timing at one batch size: milliseconds per batch call (median and best of the
/// timed calls, after one untimed warm-up call that also compiles a GPU's kernels).
fn time_calls(repeats: usize, mut call: impl FnMut() -> Result<(), String>) -> Result<(f64, f64, f64), String> {
    let t = std::time::Instant::now();
    call()?;
    let first_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut ms = Vec::with_capacity(repeats);
    for _ in 0..repeats {
        let t = std::time::Instant::now();
        call()?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    ms.sort_by(f64::total_cmp);
    Ok((ms[ms.len() / 2], ms[0], first_ms))
}

/// A 3×3 neighbourhood of 128 m tiles (metres) with ridges of a few hundred metres, the TCM's
/// input for phase `phase`'s known neighbours.
fn tcm_input(phase: usize, k: usize) -> Vec<f32> {
    use terrain::models::tcm::{TILE_PX, assemble_input, phase_mask};
    let tiles: Vec<Vec<f32>> = (0..9)
        .map(|t| {
            (0..TILE_PX * TILE_PX)
                .map(|p| {
                    let (x, y) = ((t % 3 * TILE_PX + p % TILE_PX) as f32, (t / 3 * TILE_PX + p / TILE_PX) as f32);
                    1500.0 + 300.0 * (x * 0.07 + k as f32).sin() * (y * 0.05).cos() + 80.0 * (x * 0.31 + y * 0.17).sin()
                })
                .collect()
        })
        .collect();
    let mask = phase_mask(phase);
    let known: [Option<&[f32]>; 9] = std::array::from_fn(|t| mask[t].then_some(tiles[t].as_slice()));
    let centres: [f32; 9] = std::array::from_fn(|t| tiles[t][TILE_PX * TILE_PX / 2]);
    assemble_input(&known, &centres, &[1.27; 9], 42 + k as u64)
}

/// The ×4 step's inputs for one window (metres in, channel-first out).
fn grow_input(k: usize) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    use terrain::models::grow::{WINDOW, assemble};
    let h: Vec<f32> = (0..WINDOW * WINDOW).map(|p| 900.0 + 250.0 * ((p % WINDOW) as f32 * 0.21 + k as f32).sin() * ((p / WINDOW) as f32 * 0.13).cos()).collect();
    assemble(&h, 42, 64 * k as i64, -17)
}

/// `terrain tile-bench`: for each batch size, one JSON line per model with the median and
/// best milliseconds per batch call and per tile, the first (warm-up) call's milliseconds,
/// and where it ran. `gpu`: burn's wgpu backend on the default Vulkan adapter; else the CPU
/// kernels on `threads` threads (default: every core).
pub(crate) fn tile_bench(batches: &[u32], repeats: usize, threads: Option<u32>, gpu: bool, weights: Option<PathBuf>) -> Result<(), String> {
    use burn::tensor::{Tensor, TensorData};
    use terrain::models::grow::{Grow, GrowCpu, GrowScratch, WINDOW};
    use terrain::models::tcm::{CONTEXT_PX, IN_CHANNELS, Tcm, TcmCpu, TcmScratch};
    use terrain::world::learned::{GROW_FILE, TCM_FILE};
    let dir = weights_dir(weights);
    let read = |f: &str| std::fs::read(dir.join(f)).map_err(|e| format!("cannot read {}: {e}", dir.join(f).display()));
    let (tcm_bytes, grow_bytes) = (read(TCM_FILE)?, read(GROW_FILE)?);
    let threads = threads.map_or_else(terrain::models::cpu::default_threads, |t| t as usize);
    let (gpu_models, place) = if gpu {
        let device = terrain::models::native_gpu()?;
        let tcm = terrain::models::load_burnpack(Tcm::new(&device), &tcm_bytes).map_err(|e| e.to_string())?;
        let grow = terrain::models::load_burnpack(Grow::new(&device), &grow_bytes).map_err(|e| e.to_string())?;
        (Some((device, tcm, grow)), adapter_names())
    } else {
        (None, cpu_place(threads))
    };
    let (tcm_cpu, grow_cpu) = (TcmCpu::from_burnpack(&tcm_bytes).map_err(|e| e.to_string())?, GrowCpu::from_burnpack(&grow_bytes).map_err(|e| e.to_string())?);
    // The integer-exact networks the world runs, where these weights have calibrations.
    let models = terrain::world::learned::LearnedModels::from_bytes(&tcm_bytes, &grow_bytes).map_err(|e| e.to_string())?;
    let (exact, grow_exact) = (models.exact, models.grow_exact);
    for &b in batches {
        let b = b as usize;
        let tcm_in: Vec<Vec<f32>> = (0..b).map(|k| tcm_input(k % 4, k)).collect();
        let grow_in: Vec<(Vec<f32>, Vec<f32>, Vec<f32>)> = (0..b).map(grow_input).collect();
        let (mut exact_gpu, mut grow_exact_gpu) = (None, None);
        let (tcm_t, grow_t) = match &gpu_models {
            Some((device, tcm, grow)) => {
                let stack = |parts: Vec<&Vec<f32>>, c: usize, s: usize| {
                    Tensor::<4>::from_data(TensorData::new(parts.into_iter().flatten().copied().collect::<Vec<f32>>(), [b, c, s, s]), device)
                };
                let tcm_t = time_calls(repeats, || {
                    let y = tcm.forward(stack(tcm_in.iter().collect(), IN_CHANNELS, CONTEXT_PX));
                    y.into_data().try_to_vec::<f32>().map(drop).map_err(|e| format!("{e:?}"))
                })?;
                let grow_t = time_calls(repeats, || {
                    let (x, n64, n32) = (grow_in.iter().map(|g| &g.0).collect(), grow_in.iter().map(|g| &g.1).collect(), grow_in.iter().map(|g| &g.2).collect());
                    let y = grow.forward(stack(x, 6, WINDOW), stack(n64, 1, 2 * WINDOW), stack(n32, 1, 4 * WINDOW));
                    y.into_data().try_to_vec::<f32>().map(drop).map_err(|e| format!("{e:?}"))
                })?;
                if let Some(exact) = &exact {
                    let m = exact.to_burn(device).map_err(|e| e.to_string())?;
                    let t = time_calls(repeats, || {
                        let y = exact.forward_burn(&m, stack(tcm_in.iter().collect(), IN_CHANNELS, CONTEXT_PX));
                        y.into_data().try_to_vec::<f32>().map(drop).map_err(|e| format!("{e:?}"))
                    })?;
                    exact_gpu = Some(t);
                }
                if let Some(exact) = &grow_exact {
                    let m = exact.to_burn(device).map_err(|e| e.to_string())?;
                    let t = time_calls(repeats, || {
                        let (x, n64, n32) = (grow_in.iter().map(|g| &g.0).collect(), grow_in.iter().map(|g| &g.1).collect(), grow_in.iter().map(|g| &g.2).collect());
                        let y = exact.forward_burn(&m, stack(x, 6, WINDOW), stack(n64, 1, 2 * WINDOW), stack(n32, 1, 4 * WINDOW));
                        y.into_data().try_to_vec::<f32>().map(drop).map_err(|e| format!("{e:?}"))
                    })?;
                    grow_exact_gpu = Some(t);
                }
                (tcm_t, grow_t)
            }
            None => {
                let (mut ts, mut gs) = (TcmScratch::default(), GrowScratch::default());
                let tcm_t = time_calls(repeats, || {
                    tcm_in.iter().for_each(|x| drop(std::hint::black_box(tcm_cpu.forward(x, &mut ts, threads))));
                    Ok(())
                })?;
                let grow_t = time_calls(repeats, || {
                    grow_in.iter().for_each(|(x, a, c)| drop(std::hint::black_box(grow_cpu.forward(x, a, c, WINDOW, &mut gs, threads))));
                    Ok(())
                })?;
                (tcm_t, grow_t)
            }
        };
        let mut rows = vec![("tcm_128m", tcm_t), ("grow_32m", grow_t)];
        if let Some(t) = exact_gpu {
            rows.push(("tcm_128m_exact", t));
        } else if let (None, Some(exact)) = (&gpu_models, &exact) {
            let mut ts = TcmScratch::default();
            rows.push((
                "tcm_128m_exact",
                time_calls(repeats, || {
                    tcm_in.iter().for_each(|x| drop(std::hint::black_box(exact.forward(x, &mut ts, threads))));
                    Ok(())
                })?,
            ));
        }
        if let Some(t) = grow_exact_gpu {
            rows.push(("grow_32m_exact", t));
        } else if let (None, Some(exact)) = (&gpu_models, &grow_exact) {
            let mut gs = GrowScratch::default();
            rows.push((
                "grow_32m_exact",
                time_calls(repeats, || {
                    grow_in.iter().for_each(|(x, a, c)| drop(std::hint::black_box(exact.forward(x, a, c, WINDOW, &mut gs, threads))));
                    Ok(())
                })?,
            ));
        }
        for (model, (median, best, first)) in rows {
            println!(
                "{}",
                serde_json::json!({ "model": model, "batch": b, "on": place, "repeats": repeats, "ms_per_batch": median, "min_ms_per_batch": best, "ms_per_tile": median / b as f64, "first_call_ms": first })
            );
        }
    }
    Ok(())
}

/// Where the CPU kernels run: "cpu kernels (avx512), 2 threads".
fn cpu_place(threads: usize) -> String {
    format!("cpu kernels ({}), {threads} thread{}", terrain::models::cpu::Kernels::chosen().widest(), if threads == 1 { "" } else { "s" })
}

/// Where `--gpu` runs: the Vulkan adapters' names and drivers (the default one among them).
#[cfg(feature = "train")]
fn adapter_names() -> String {
    format!("burn wgpu: {}", terrain::train::vulkan_adapters().join("; "))
}

/// Where `--gpu` runs (without the `train` feature the adapters are not listed).
#[cfg(not(feature = "train"))]
fn adapter_names() -> String {
    "burn wgpu (default Vulkan adapter)".into()
}

/// `terrain tcm-calibrate`: the integer-exact TCM's activation grids for the weights in
/// `weights`, from the network inputs of the float world's tiles −3…2 of seeds 1…`seeds`.
pub(crate) fn tcm_calibrate(seeds: u64, weights: Option<PathBuf>) -> Result<(), String> {
    use terrain::grid::coord::TileCoord;
    use terrain::models::tcm::{TcmCpu, TcmExact};
    use terrain::world::learned::{GROW_FILE, LearnedModels, LearnedSource, TCM_FILE};
    let dir = weights_dir(weights);
    let read = |f: &str| std::fs::read(dir.join(f)).map_err(|e| format!("cannot read {}: {e}", dir.join(f).display()));
    let (tcm_bytes, grow_bytes) = (read(TCM_FILE)?, read(GROW_FILE)?);
    let tcm = TcmCpu::from_burnpack(&tcm_bytes).map_err(|e| e.to_string())?;
    let grow = terrain::models::grow::GrowCpu::from_burnpack(&grow_bytes).map_err(|e| e.to_string())?;
    let float = LearnedSource::new(std::sync::Arc::new(LearnedModels::from_parts(tcm.clone(), None, grow, None, "float")), terrain::models::cpu::default_threads());
    let inputs: Vec<Vec<f32>> =
        (1..=seeds).flat_map(|seed| (0..36).map(move |t| (seed, TileCoord::new(t % 6 - 3, t / 6 - 3)))).map(|(seed, c)| float.network_input(seed, c).0).collect();
    let exps = TcmExact::calibrate(&tcm, &inputs).map_err(|e| e.to_string())?;
    let exact = TcmExact::new(&tcm, &exps).map_err(|e| e.to_string())?;
    let (mut sq, mut var, mut n) = (0f64, 0f64, 0f64);
    let mut s = Default::default();
    for x in &inputs {
        let (a, b) = (tcm.forward(x, &mut s, 1), exact.forward(x, &mut s, 1));
        let mean = a.iter().map(|&v| v as f64).sum::<f64>() / a.len() as f64;
        for (p, q) in a.iter().zip(&b) {
            sq += ((p - q) as f64).powi(2);
            var += (*p as f64 - mean).powi(2);
            n += 1.0;
        }
    }
    let rms_m = (sq / n).sqrt() * terrain::models::tcm::HEIGHT_SCALE_M as f64;
    let sd_m = (var / n).sqrt() * terrain::models::tcm::HEIGHT_SCALE_M as f64;
    println!(
        "{}",
        serde_json::json!({ "tcm_hash": terrain::models::weights_hash(&[&tcm_bytes]), "act_exp": exps, "inputs": inputs.len(), "largest_sum": exact.bound(), "rms_vs_float_m": rms_m, "float_tile_sd_m": sd_m })
    );
    Ok(())
}

/// `terrain grow-calibrate`: the integer-exact ×4 step's grids for the weights in `weights`
/// (default `weights/`), from the ×4 windows of the world's tiles −3…2 of seeds 1…`seeds`;
/// prints JSON: the weight file's hash, the grids, the largest sum and the RMS (metres) of
/// the integer residual from the float one beside the float residual's own.
pub(crate) fn grow_calibrate(seeds: u64, weights: Option<PathBuf>) -> Result<(), String> {
    use terrain::grid::coord::TileCoord;
    use terrain::models::grow::{GrowCpu, GrowExact, GrowScratch, HEIGHT_SCALE_M, WINDOW};
    use terrain::world::learned::{GROW_FILE, LearnedModels, LearnedSource};
    let dir = weights_dir(weights);
    let grow_bytes = std::fs::read(dir.join(GROW_FILE)).map_err(|e| format!("cannot read {}: {e}", dir.join(GROW_FILE).display()))?;
    let grow = GrowCpu::from_burnpack(&grow_bytes).map_err(|e| e.to_string())?;
    let world = LearnedSource::new(std::sync::Arc::new(LearnedModels::load_dir(&dir).map_err(|e| e.to_string())?), terrain::models::cpu::default_threads());
    let inputs: Vec<_> = (1..=seeds).flat_map(|seed| (0..36).map(move |t| (seed, TileCoord::new(t % 6 - 3, t / 6 - 3)))).map(|(seed, c)| world.grow_input(seed, c).1).collect();
    let exps = GrowExact::calibrate(&grow, &inputs, WINDOW).map_err(|e| e.to_string())?;
    let exact = GrowExact::new(&grow, &exps).map_err(|e| e.to_string())?;
    let (mut sq, mut own, mut n) = (0f64, 0f64, 0f64);
    let mut s = GrowScratch::default();
    let threads = terrain::models::cpu::default_threads();
    for (x, a, b) in &inputs {
        let (p, q) = (grow.forward(x, a, b, WINDOW, &mut s, threads), exact.forward(x, a, b, WINDOW, &mut s, threads));
        for (u, v) in p.iter().zip(&q) {
            sq += ((u - v) as f64).powi(2);
            own += (*u as f64).powi(2);
            n += 1.0;
        }
    }
    let m = HEIGHT_SCALE_M as f64;
    println!(
        "{}",
        serde_json::json!({ "grow_hash": terrain::models::weights_hash(&[&grow_bytes]), "exps": exps, "inputs": inputs.len(), "largest_sum": exact.bound(), "rms_vs_float_m": (sq / n).sqrt() * m, "float_residual_rms_m": (own / n).sqrt() * m })
    );
    Ok(())
}

/// `terrain world-bench`: `tiles` world tiles of seed 1 from empty caches, their network work
/// run batch by batch ([`terrain::world::learned::LearnedSource::network_work`]) on the CPU
/// kernels (`threads`) or on burn's wgpu backend (`gpu`); prints JSON: where it ran, the
/// milliseconds per world tile in all and by part, and the batches (kind and items).
pub(crate) fn world_bench(tiles: u32, threads: Option<u32>, gpu: bool, weights: Option<PathBuf>) -> Result<(), String> {
    use terrain::grid::coord::TileCoord;
    use terrain::world::learned::{LearnedModels, LearnedSource, NetworkWork};
    use terrain::world::tile::{Neighbourhood, TileSource};
    let threads = threads.map_or_else(terrain::models::cpu::default_threads, |t| t as usize);
    let mut models = LearnedModels::load_dir(&weights_dir(weights)).map_err(|e| e.to_string())?;
    let on = if gpu {
        models = models.with_networks_on(&terrain::models::native_gpu()?)?;
        adapter_names()
    } else {
        cpu_place(threads)
    };
    let models = std::sync::Arc::new(models);
    let world = LearnedSource::new(models.clone(), threads);
    let mut s = Default::default();
    let (mut batches, mut network_ms) = (Vec::new(), 0.0);
    let t0 = std::time::Instant::now();
    for i in 0..tiles as i32 {
        let c = TileCoord::new(i, 0);
        loop {
            let work = world.network_work(1, c);
            if work == NetworkWork::None {
                break;
            }
            let t = std::time::Instant::now();
            let out = models.run_work(&work, &mut s, threads)?;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            network_ms += ms;
            batches.push(serde_json::json!({ "kind": if matches!(work, NetworkWork::Tcm(_)) { "tcm" } else { "grow" }, "items": work.len(), "ms": ms }));
            world.accept(1, &work.keys(), out, ms)?;
        }
        std::hint::black_box(world.generate(1, c, &Neighbourhood::default()));
    }
    let total_ms = t0.elapsed().as_secs_f64() * 1e3;
    let spent = world.time_spent();
    let per = |ms: f64| ms / tiles as f64;
    println!(
        "{}",
        serde_json::json!({
            "on": on,
            "tiles": tiles,
            "ms_per_world_tile": per(total_ms),
            "networks_ms_per_world_tile": per(network_ms),
            "by_part_ms_per_world_tile": {
                "macro_field": per(spent.macro_field.ms), "tcm": per(spent.tcm.ms), "seams_128m": per(spent.seams_128m.ms), "erosion": per(spent.erosion.ms),
                "grow": per(spent.grow.ms), "carve_32m": per(spent.carve_32m.ms), "breach_32m": per(spent.breach_32m.ms),
            },
            "network_tiles": { "tcm": spent.tcm.runs, "grow": spent.grow.runs },
            "batches": batches,
        })
    );
    Ok(())
}
