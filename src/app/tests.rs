//! Tests of the application core.

use super::*;
use crate::world::TILE_SAMPLES;
use crate::world::refine::INPUT_SIDE;

/// Settings of a procedural world of `radius` tiles (the tests below stream it here, on
/// this thread).
fn procedural(radius_tiles: f64) -> ShareState {
    ShareState { radius_tiles, source: SourceKind::Procedural, ..ShareState::default() }
}

#[test]
fn frames_stream_tiles_and_select_nodes() {
    let mut app = TerrainApp::new(procedural(2.0));
    let mut drawn = 0;
    for _ in 0..200 {
        let (nodes, p) = app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        drawn = nodes.len();
        assert_eq!(p.size, [800, 600]);
        if app.stats().tiles_pending == 0 && drawn > 0 {
            break;
        }
    }
    let s = app.stats();
    assert_eq!(s.tiles_pending, 0);
    assert!(drawn > 0 && s.tiles_generated >= 25, "{s:?}");
    assert!(s.max_depth_drawn == BASE_DATA_DEPTH, "near nodes reach 32 m: {s:?}");
    let ground = app.ground_at(app.camera.position_m.x, app.camera.position_m.z).unwrap() as f64;
    assert!(app.camera.position_m.y > ground);
}

#[test]
fn autopilot_flies_and_reaches_new_tiles() {
    let mut app = TerrainApp::new(ShareState { autopilot_mps: 2000.0, ..procedural(2.0) });
    let start = app.camera.position_m;
    for _ in 0..300 {
        app.frame(&ControlInput::default(), 1.0 / 30.0, [640, 480]);
    }
    let moved = (app.camera.position_m - start).length();
    assert!(moved > 15_000.0, "moved {moved} m");
    assert!(app.stats().tiles_evicted > 0 || app.stats().tiles_generated > 40, "{:?}", app.stats());
    assert!(app.stats().tiles_cached <= app.stats().tiles_capacity);
}

/// With refinement on (untrained, i.e. bicubic, models on the CPU), looking down from low
/// above rough ground draws nodes below 32 m, built from TEM patches.
#[test]
fn refinement_draws_nodes_below_the_base_depth() {
    let tem = crate::models::tem::TemSet::untrained(&crate::models::tem::Exec::cpu());
    let mut app = TerrainApp::new(procedural(1.0));
    app.set_refinement(Some("CPU".into()));
    for _ in 0..60 {
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    }
    // Low above the ground, looking down ahead.
    let p = app.camera.position_m;
    let g = app.ground_at(p.x, p.z).unwrap() as f64;
    app.camera.position_m.y = g + 60.0;
    app.camera.pitch = -0.6;
    let mut ran = 0;
    for _ in 0..80 {
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        ran += app.refine_blocking(&tem, REFINE_BATCH).unwrap();
    }
    let s = app.stats().clone();
    assert!(ran > 0 && s.quads_made as usize == ran, "{s:?}");
    assert!(s.max_depth_drawn > BASE_DATA_DEPTH, "refined nodes drawn: {s:?}");
    assert!(s.ms_per_quad > 0.0 && s.refine_backend == "CPU");
    app.set_refinement(None);
    app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    assert!(app.stats().max_depth_drawn <= BASE_DATA_DEPTH);
}

/// The page's export at a TEM spacing: before any patch is made it says so; once level-0
/// patches are made around the eye, the export is a square of whole patches at 16 m, every
/// sample the stored patch pixel at its place (its corner where those pixels lie in the
/// world's frame); a level the TEM does not have is refused.
#[test]
fn the_view_exports_its_learned_detail_at_16_m_where_it_is_refined() {
    let tem = crate::models::tem::TemSet::untrained(&crate::models::tem::Exec::cpu());
    let mut app = low_refining_app();
    let before = app.export_refined(0).unwrap_err();
    assert!(before.contains("Nothing is refined to 16 m yet"), "{before}");
    for _ in 0..80 {
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        app.refine_blocking(&tem, REFINE_BATCH).unwrap();
    }
    let hf = app.export_refined(0).unwrap();
    assert_eq!(hf.spacing_m, 16.0);
    assert!(hf.width == hf.height && hf.width.is_multiple_of(128) && hf.width >= 128, "{} × {}", hf.width, hf.height);
    let g = hf.geo.expect("placed in the world's frame");
    let (px0, py0) = (((g.origin_m[0] + 16.0) / 16.0).round() as i64, ((16.0 - g.origin_m[1]) / 16.0).round() as i64);
    for k in (0..hf.data.len()).step_by(97) {
        let (x, y) = ((k % hf.width) as i64, (k / hf.width) as i64);
        assert_eq!(Some(hf.data[k]), app.refine.pixel(0, px0 + x, py0 + y), "sample {k}");
    }
    eprintln!("exported {} × {} samples at 16 m", hf.width, hf.height);
    assert!(app.export_refined(9).is_err());
}

/// An app with refinement on, low above rough ground looking down, after enough frames
/// that the quadtree asks for refined patches.
fn low_refining_app() -> TerrainApp {
    let mut app = TerrainApp::new(procedural(1.0));
    app.set_refinement(Some("CPU".into()));
    for _ in 0..60 {
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    }
    let p = app.camera.position_m;
    app.camera.position_m.y = app.ground_at(p.x, p.z).unwrap() as f64 + 60.0;
    app.camera.pitch = -0.6;
    app
}

/// Runs up to 20 frames until the app asks for TEM jobs; returns them (empty if it never
/// did).
fn frames_until_jobs(app: &mut TerrainApp) -> Vec<RefineJob> {
    for _ in 0..20 {
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        let jobs = app.refine_jobs(REFINE_BATCH);
        if !jobs.is_empty() {
            return jobs;
        }
    }
    Vec::new()
}

/// A TEM batch still running when the world changes (here: a new seed) comes back tagged
/// with the old epoch and is dropped: nothing of the old world lands in the new one. The
/// same batch delivered for the current world is stored (control).
#[test]
fn a_batch_of_an_older_world_is_dropped() {
    let mut app = low_refining_app();
    let jobs = frames_until_jobs(&mut app);
    assert!(!jobs.is_empty(), "the low view asks for refined patches");
    let old_epoch = jobs[0].epoch;
    assert_eq!(old_epoch, app.epoch());
    let keys: Vec<PatchKey> = jobs.iter().map(|j| j.key).collect();
    let raw = vec![123.0f32; (2 * INPUT_SIDE).pow(2) * keys.len()];
    // The world changes while the batch runs.
    let new = ShareState { seed: app.settings().seed + 1, ..app.share_state() };
    app.apply(new);
    app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    assert_eq!(app.epoch(), old_epoch + 1);
    app.refine_done(old_epoch, &keys, &raw, 10.0).unwrap();
    let s = app.refine_stats();
    assert_eq!((s.quads_made, s.cached, s.stale_dropped), (0, 0, keys.len() as u64), "stale batch must not land: {s:?}");
    // The same kind of batch for the current world lands.
    let keys: Vec<PatchKey> = frames_until_jobs(&mut app).iter().map(|j| j.key).collect();
    app.refine_done(app.epoch(), &keys, &vec![5.0f32; (2 * INPUT_SIDE).pow(2) * keys.len()], 10.0).unwrap();
    assert_eq!(app.refine_stats().quads_made, keys.len() as u64);
    assert!(!keys.is_empty());
}

/// A TEM batch with one NaN or one infinite height is refused whole, with an error that
/// counts them: no patch of it is stored, and its patches are asked for again.
#[test]
fn a_tem_batch_with_a_height_that_is_not_finite_is_refused_and_asked_for_again() {
    for bad in [f32::NAN, f32::INFINITY] {
        let mut app = low_refining_app();
        let jobs = frames_until_jobs(&mut app);
        let keys: Vec<PatchKey> = jobs.iter().map(|j| j.key).collect();
        let mut raw = vec![5.0f32; (2 * INPUT_SIDE).pow(2) * keys.len()];
        let mid = raw.len() / 2;
        raw[mid] = bad;
        let e = app.refine_done(app.epoch(), &keys, &raw, 10.0).unwrap_err();
        assert!(e.contains("1 heights that are not finite"), "{e}");
        assert_eq!((app.refine_stats().quads_made, app.refine_stats().cached), (0, 0));
        let again: Vec<PatchKey> = frames_until_jobs(&mut app).iter().map(|j| j.key).collect();
        assert!(keys.iter().all(|k| again.contains(k)), "the refused patches are asked for again");
    }
}

/// While no refinement jobs are taken (inference busy or rate-limited), a long flight keeps
/// the request list to this frame's wants: never more requests than nodes drawn, and the
/// last third of the flight no higher than the first.
#[test]
fn patch_requests_stay_bounded_while_no_jobs_are_taken() {
    let mut app = low_refining_app();
    let mut counts = Vec::new();
    for _ in 0..600 {
        app.camera.position_m.x += 40.0;
        let p = app.camera.position_m;
        if let Some(g) = app.ground_at(p.x, p.z) {
            app.camera.position_m.y = g as f64 + 60.0;
        }
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        let (r, drawn) = (app.refine_stats().requests, app.stats().nodes_drawn);
        assert!(r <= drawn, "{r} requests for {drawn} nodes drawn");
        counts.push(r);
    }
    let third = counts.len() / 3;
    let (first, last) = (counts[..third].iter().max().unwrap(), counts[2 * third..].iter().max().unwrap());
    assert!(*first > 0, "the flight asks for refinement");
    assert!(*last <= first + first / 2, "requests grew from {first} to {last}");
}

/// A link of a moved camera reproduces its view: the eye to the centimetre, heading and
/// pitch to 10⁻⁵ rad.
#[test]
fn share_state_reproduces_the_view() {
    let mut a = TerrainApp::new(procedural(4.0));
    a.frame(&ControlInput { look_px: glam::Vec2::new(40.0, 10.0), movement: glam::Vec3::Z, ..Default::default() }, 0.1, [320, 200]);
    let link = a.share_state().to_fragment();
    let b = TerrainApp::new(ShareState::from_fragment(&link).unwrap());
    assert!((a.camera.position_m - b.camera.position_m).abs().max_element() <= 0.005, "{} vs {}", a.camera.position_m, b.camera.position_m);
    assert!((a.camera.yaw - b.camera.yaw).abs() <= 6e-6 && (a.camera.pitch - b.camera.pitch).abs() <= 6e-6);
}

/// Heights standing in for a learned tile: a plane through the tile's corner, so tiles
/// differ by coordinate.
fn fake_tile(c: TileCoord) -> Vec<f32> {
    (0..TILE_SAMPLES * TILE_SAMPLES).map(|p| (c.i * 7 + c.j * 3) as f32 + (p % TILE_SAMPLES) as f32 * 0.01).collect()
}

/// The learned world asks for nothing while its models load, then for at most
/// TILE_JOBS_IN_FLIGHT tiles at a time, nearest first; tiles handed back fill the world
/// until nothing is pending; a tile made for the previous world (seed changed while it
/// ran) is dropped and counted stale, and bad heights are refused.
#[test]
fn learned_tiles_arrive_as_jobs_and_stale_ones_are_dropped() {
    let mut app = TerrainApp::new(ShareState { radius_tiles: 1.0, ..ShareState::default() });
    app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    assert_eq!(app.source(), SourceKind::Learned);
    assert!(app.tile_jobs().is_empty(), "no jobs while the models load");
    assert!(app.stats().tiles_pending > 0 && app.stats().tiles_generated == 0);
    assert_eq!(app.set_learned(LearnedStatus::Ready { hash: "abc".into() }), None);
    let eye = app.camera.position_m;
    let mut made = 0;
    for _ in 0..200 {
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        let jobs = app.tile_jobs();
        assert!(jobs.len() <= TILE_JOBS_IN_FLIGHT);
        if made == 0 {
            assert_eq!(jobs[0].key, TileCoord::containing(eye.x, eye.z), "the tile under the camera comes first");
        }
        for j in &jobs {
            assert!(app.tile_done(j, fake_tile(j.key), 5.0));
            made += 1;
        }
        if jobs.is_empty() {
            break;
        }
    }
    app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    let s = app.stats().clone();
    assert_eq!((s.tiles_pending, s.tiles_generated, s.tile_jobs.done), (0, made, made), "{s:?}");
    assert!(s.nodes_drawn > 0 && s.source == "learned" && (s.ms_per_tile - 5.0).abs() < 1e-9);
    assert_eq!(app.share_state().weights.as_deref(), Some("abc"));
    // A tile in flight when the seed changes belongs to the old world.
    app.camera.position_m.x += 3.0 * TILE_SIZE_M;
    let old = app.tile_jobs();
    assert!(!old.is_empty());
    app.apply_settings(ShareState { seed: 99, ..app.settings().clone() });
    assert!(!app.tile_done(&old[0], fake_tile(old[0].key), 5.0), "stale tile landed");
    assert_eq!(app.world.job_stats().stale, 1);
    let new = app.tile_jobs();
    assert!(!app.tile_done(&new[0], vec![f32::NAN; TILE_SAMPLES * TILE_SAMPLES], 5.0), "NaN heights refused");
    assert!(!app.tile_done(&new[1], vec![0.0; 3], 5.0), "a short tile refused");
    assert_eq!(app.world.job_stats().failed, 2);
    assert!(!app.world.contains(new[0].key) && !app.world.contains(old[0].key));
}

/// Procedural tiles made elsewhere (the page's CPU worker): the app asks for them as jobs
/// and makes none itself, and the tiles handed back (made by the same generator) give the
/// same view checksum as an app that made them itself; without the worker it makes them
/// here again.
#[test]
fn procedural_tiles_made_elsewhere_give_the_same_view() {
    let mut here = TerrainApp::new(procedural(1.0));
    let mut there = TerrainApp::new(procedural(1.0));
    there.set_procedural_elsewhere(true);
    let src = ProceduralSource::new(there.settings().noise);
    for _ in 0..200 {
        here.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        there.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        let jobs = there.tile_jobs();
        for j in &jobs {
            let t = src.generate(there.settings().seed, j.key, &crate::world::Neighbourhood::default());
            assert!(there.tile_done(j, t.heights.to_vec(), 1.0));
        }
        if jobs.is_empty() && here.stats().tiles_pending == 0 && there.stats().tiles_pending == 0 {
            break;
        }
    }
    here.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    there.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    let (a, b) = (here.stats().clone(), there.stats().clone());
    assert_eq!(a.tile_jobs.done, 0, "the app that makes its own tiles takes no jobs");
    assert_eq!(b.tile_jobs.done, b.tiles_generated, "every tile of the other came as a job: {b:?}");
    assert!(b.tiles_generated >= 9 && b.nodes_drawn > 0, "{b:?}");
    assert_eq!(a.view_checksum, b.view_checksum);
    there.set_procedural_elsewhere(false);
    assert!(there.tile_jobs().is_empty());
    there.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    assert!(there.stats().tiles_generated > 0, "made here again: {:?}", there.stats());
}

/// Models that fail leave the procedural world in place of the learned one: it streams,
/// and the share link names it; a link made with other weights gets a note once the
/// models are ready.
#[test]
fn failed_models_fall_back_to_the_procedural_world() {
    let mut app = TerrainApp::new(ShareState { radius_tiles: 1.0, ..ShareState::default() });
    app.set_learned(LearnedStatus::Failed("tcm_128m.bpk: HTTP 404".into()));
    for _ in 0..30 {
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
    }
    assert_eq!(app.source(), SourceKind::Procedural);
    assert!(app.tile_jobs().is_empty());
    let s = app.stats();
    assert!(s.tiles_generated > 0 && s.source == "procedural", "{s:?}");
    let link = app.share_state();
    assert_eq!((link.source, link.weights), (SourceKind::Procedural, None));
    let mut linked = TerrainApp::new(ShareState { weights: Some("0ld".into()), ..ShareState::default() });
    let note = linked.set_learned(LearnedStatus::Ready { hash: "new".into() }).expect("a note");
    assert!(note.contains("0ld") && note.contains("new"), "{note}");
    let mut same = TerrainApp::new(ShareState { weights: Some("new".into()), ..ShareState::default() });
    assert_eq!(same.set_learned(LearnedStatus::Ready { hash: "new".into() }), None);
}

fn sketch_app() -> TerrainApp {
    let mut app = TerrainApp::new(ShareState { radius_tiles: 1.0, source: SourceKind::Sketch, ..ShareState::default() });
    app.set_sketch_models(LearnedStatus::Ready { hash: "00000001".into() });
    app
}

#[test]
fn a_sketch_becomes_the_world_one_job_at_a_time_and_older_terrain_is_dropped() {
    let mut app = sketch_app();
    let jobs = app.sketch_jobs();
    assert_eq!(jobs.len(), 1, "the first sketch is asked for");
    assert!(app.sketch_jobs().is_empty(), "one job in flight at most");
    let (first, sketch) = jobs[0].clone();
    assert_eq!(&sketch, app.canvas.sketch());
    // Two strokes land while the first sketch is being made.
    app.canvas.set_tool(crate::sketch::canvas::Tool::Ridge);
    app.canvas.press(10.0, 10.0);
    app.canvas.drag(100.0, 10.0);
    app.canvas.release();
    let ramp: Vec<f32> = (0..SKETCH_PX * SKETCH_PX).map(|p| (p % SKETCH_PX) as f32).collect();
    assert!(app.sketch_done(&first, ramp.clone(), 5.0).unwrap(), "the first terrain is shown");
    let relief = app.settings().relief_m as f32;
    // World sample x = 0 is sketch column 128.
    assert_eq!(app.tile_heights(TileCoord::new(0, 0)), None, "tiles come with the next frame");
    app.frame(&ControlInput::default(), 0.016, [64, 64]);
    let h = app.tile_heights(TileCoord::new(0, 0)).expect("the tile at the origin")[0];
    assert!((h - 128.0 / 255.0 * relief).abs() < 1e-3, "{h}");
    // The newest sketch is asked for next; its terrain replaces the first.
    let (second, _) = app.sketch_jobs()[0].clone();
    assert!(second.key > first.key);
    assert!(app.sketch_done(&second, vec![255.0; SKETCH_PX * SKETCH_PX], 5.0).unwrap());
    assert!(!app.sketch_done(&first, ramp, 5.0).unwrap(), "an older sketch's terrain is dropped");
    assert!(app.sketch_jobs().is_empty(), "nothing new to make");
    assert!(app.sketch_done(&second, vec![f32::NAN; SKETCH_PX * SKETCH_PX], 1.0).is_err());
}

#[test]
fn without_the_generator_the_band_interpolation_is_shown_at_once() {
    let mut app = sketch_app();
    app.set_sketch_models(LearnedStatus::Failed("no weights".into()));
    assert!(app.sketch_jobs().is_empty());
    let shown = app.sketch_terrain().unwrap();
    assert_eq!(shown, crate::sketch::baseline::interpolate(app.canvas.sketch()).as_slice());
    let link = app.share_state();
    assert_eq!(link.source, SourceKind::Sketch);
    assert_eq!(crate::sketch::code::decode(link.sketch.as_deref().unwrap()).unwrap(), *app.canvas.sketch());
}

/// While the procedural world stands in for learned models that failed, the address bar's
/// state keeps the learned world and the linked weights the user asked for (a reload asks for
/// them again), and "Copy link" gives the world shown.
#[test]
fn the_address_keeps_the_asked_world_while_a_stand_in_is_shown() {
    let mut app = TerrainApp::new(ShareState { weights: Some("0ld".into()), ..ShareState::default() });
    app.set_learned(LearnedStatus::Failed("tcm_128m.bpk: HTTP 503".into()));
    let asked = app.asked_state();
    assert_eq!((asked.source, asked.weights.as_deref()), (SourceKind::Learned, Some("0ld")));
    assert!(asked.to_fragment().contains("src=tcm&w=0ld"), "{}", asked.to_fragment());
    let shown = app.share_state();
    assert_eq!((shown.source, shown.weights), (SourceKind::Procedural, None));
    // Once the models load, both name them.
    app.set_learned(LearnedStatus::Ready { hash: "0ld".into() });
    assert_eq!(app.asked_state().weights.as_deref(), Some("0ld"));
    assert_eq!(app.share_state().source, SourceKind::Learned);
}

/// A sketch link made with other generator weights gets a note once the sketch models are
/// ready (as the learned world's links do); with the same weights, none.
#[test]
fn a_sketch_link_with_other_weights_gets_a_note_when_the_generator_is_ready() {
    let mut app = TerrainApp::new(ShareState { source: SourceKind::Sketch, weights: Some("0ld".into()), ..ShareState::default() });
    let note = app.set_sketch_models(LearnedStatus::Ready { hash: "new".into() }).expect("a note");
    assert!(note.contains("sketch-generator weights 0ld") && note.contains("new"), "{note}");
    let mut same = TerrainApp::new(ShareState { source: SourceKind::Sketch, weights: Some("new".into()), ..ShareState::default() });
    assert_eq!(same.set_sketch_models(LearnedStatus::Ready { hash: "new".into() }), None);
}

/// On a device whose buffers hold 600 node meshes (a budget of 300 nodes), the widest view a
/// link may ask for (radius 16 tiles, LOD target 0.5 px) of the procedural world selects
/// more nodes than that without the budget; with it, the app raises its LOD target until the
/// view fits and, from frame 40 of 60 on, stays within 5 % of the budget (nodes are built a
/// few per frame, so the count may pass it by a few before the target moves; the renderer's
/// buffer holds twice the budget); at the default settings a 256 MiB device's budget changes
/// nothing.
#[test]
fn the_view_fits_the_gpus_node_budget() {
    let small = crate::render::node_budget(600 * crate::render::MESH_BYTES);
    assert_eq!(small, 300);
    let run = |s: ShareState, budget: Option<usize>| {
        let mut app = TerrainApp::new(s);
        if let Some(b) = budget {
            app.set_node_budget(b);
        }
        let eye = app.camera.position_m;
        app.world.update(eye.x, eye.z, 1e9);
        let drawn: Vec<usize> = (0..60).map(|_| app.frame(&ControlInput::default(), 1.0 / 60.0, [1280, 800]).0.len()).collect();
        (drawn, app.stats().clone())
    };
    let widest = ShareState { lod_px: 0.5, ..procedural(16.0) };
    let (free, s) = run(widest.clone(), None);
    let (fitted, f) = run(widest, Some(small));
    eprintln!("widest view: {} nodes free; {} nodes at LOD {:.2} px with a budget of {small}", free[59], fitted[59], f.lod_px_effective);
    assert!(free[59] > small && s.lod_px_effective == 0.5 && s.node_budget.is_none(), "{}", free[59]);
    assert!(fitted[40..].iter().all(|&n| n <= small + small / 20), "{fitted:?}");
    assert!(f.lod_px_effective > 0.5 && f.node_budget == Some(small));
    let (_, d) = run(procedural(4.0), Some(crate::render::node_budget(crate::render::MESH_MEMORY_BUDGET)));
    assert_eq!(d.lod_px_effective, ShareState::default().lod_px);
}

/// A new seed keeps the old picture: the first frame after it draws the previous world's
/// nodes (the same node data), no frame is empty, and once the new world has made the tiles
/// within a tile of the eye its own nodes are drawn. A camera moved elsewhere (a link to
/// another place) drops the old picture at once.
#[test]
fn a_new_seed_keeps_the_old_picture_until_the_new_world_has_its_near_tiles() {
    let mut app = TerrainApp::new(procedural(2.0));
    let frame = |app: &mut TerrainApp| app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]).0;
    let mut old = Vec::new();
    for _ in 0..300 {
        old = frame(&mut app);
        if app.stats().tiles_pending == 0 && !old.is_empty() {
            break;
        }
    }
    let old_versions: std::collections::HashSet<u64> = old.iter().map(|n| n.version).collect();
    app.apply(ShareState { seed: 99, ..app.share_state() });
    let mut switched = None;
    for k in 0..300 {
        let nodes = frame(&mut app);
        assert!(!nodes.is_empty(), "frame {k} after the new seed is empty");
        let from_old = nodes.iter().all(|n| old_versions.contains(&n.version));
        assert_eq!(from_old, app.stats().previous_world_shown, "frame {k}");
        if k == 0 {
            assert!(from_old, "the first frame after the new seed draws the old picture");
        }
        if !from_old {
            switched = Some(k);
            break;
        }
    }
    eprintln!("the new world's own nodes from frame {switched:?}");
    assert!(switched.is_some_and(|k| k > 0));
    app.apply(ShareState { seed: 5, position_m: [50_000.0, 3000.0, 50_000.0], ..app.share_state() });
    frame(&mut app);
    assert!(!app.stats().previous_world_shown, "a view elsewhere does not keep the old picture");
}

/// Frames (at most 400) until every tile and far-field tile around the eye is made and some
/// far tiles are drawn; asserts they were (more than 20 drawn) and that the view reaches the
/// far field, and returns the far ring around the eye.
fn frames_until_far_field(app: &mut TerrainApp) -> Vec<TileCoord> {
    use crate::world::stream::FAR_FIELD_M;
    for _ in 0..400 {
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        let s = app.stats();
        if s.tiles_pending == 0 && s.far_pending == 0 && s.far_drawn > 0 {
            break;
        }
    }
    let s = app.stats().clone();
    assert!(s.tiles_pending == 0 && s.far_pending == 0 && s.far_drawn > 20, "{s:?}");
    assert!(app.camera.far_m >= FAR_FIELD_M as f32);
    let eye = app.camera.position_m;
    app.world.far_ring(eye.x, eye.z)
}

/// The far field's edge never shows: seen from 1.5, 20 and 60 km up, the fog is whole
/// (≥ 99.9 %) at the slant distance to a point 61 km away at sea level, while the ground
/// straight below the eye is at most 12 % fogged.
#[test]
fn the_fog_is_whole_at_the_far_fields_edge_and_light_below_the_eye_from_any_height() {
    use crate::world::stream::FAR_FIELD_M;
    let mut app = TerrainApp::new(procedural(1.0));
    for h in [1500.0, 20_000.0, 60_000.0] {
        app.camera.position_m.y = h;
        app.frame(&ControlInput::default(), 1.0 / 60.0, [800, 600]);
        let (start, end) = app.fog_m();
        let fog = |d: f64| {
            let t = ((d as f32 - start) / (end - start).max(1.0)).clamp(0.0, 1.0);
            t * t * (3.0 - 2.0 * t)
        };
        let (edge, below) = (fog(FAR_FIELD_M.hypot(h)), fog(h));
        eprintln!("{h} m up: fog {start:.0}–{end:.0} m, at the edge {edge:.3}, below {below:.3}");
        assert!(edge >= 0.999 && below <= 0.12, "{h} m up: fog at the edge {edge}, below {below}");
        assert!(end <= app.camera.far_m);
    }
}

/// The procedural world has a far field too: once its tiles are made, the ring out to 61 km is
/// made here (a few tiles a frame) and drawn; each far tile holds the tile's own samples at
/// every 4th position (so it meets the detailed tiles exactly), and the view reaches 61 km.
#[test]
fn the_procedural_world_draws_a_far_field_of_its_own_samples() {
    use crate::world::stream::COARSE_SAMPLES;
    let mut app = TerrainApp::new(ShareState { pitch: -0.1, ..procedural(1.0) });
    let ring = frames_until_far_field(&mut app);
    let eye = app.camera.position_m;
    let c = *ring.last().expect("a far ring");
    assert!(c.distance_tiles(eye.x, eye.z) >= 14.0);
    let full = ProceduralSource::new(app.settings().noise).generate(app.settings().seed, c, &crate::world::Neighbourhood::default());
    let far = app.world.coarse(c).expect("the farthest far tile");
    let n = COARSE_SAMPLES;
    assert!((0..n * n).all(|k| far[k] == full.heights[(k / n) * 4 * crate::grid::TILE_SAMPLES + (k % n) * 4]));
}

/// The sketch world has a far field too, so its plain runs to the horizon instead of ending
/// at the detailed tiles' edge: once the sketch's terrain is here and its tiles are made, the
/// ring out to 61 km is made here and drawn, the view reaches 61 km, and a far tile next to
/// the sketch holds its tile's own samples at every 4th position.
#[test]
fn the_sketch_world_draws_a_far_field_of_its_own_samples() {
    use crate::world::stream::{COARSE_SAMPLES, FAR_FIELD_M};
    let mut app = sketch_app();
    let (job, _) = app.sketch_jobs()[0].clone();
    assert!(app.camera.far_m < FAR_FIELD_M as f32, "no far field before the sketch's terrain");
    let bumps: Vec<f32> = (0..SKETCH_PX * SKETCH_PX).map(|p| 127.5 + 127.5 * ((p % SKETCH_PX) as f32 * 0.2).sin() * ((p / SKETCH_PX) as f32 * 0.1).cos()).collect();
    assert!(app.sketch_done(&job, bumps, 5.0).unwrap());
    let ring = frames_until_far_field(&mut app);
    let eye = app.camera.position_m;
    assert!(ring.last().expect("a far ring").distance_tiles(eye.x, eye.z) >= 14.0);
    // A far tile beside the sketch (its ground still falls from the sketch's edge).
    let c = *ring.iter().min_by_key(|c| c.i.abs() + c.j.abs()).expect("a far tile");
    let full = app.world.get(c).map(|t| t.heights.clone()).unwrap_or_else(|| {
        let src = crate::world::sketched::SketchSource::new(std::sync::Arc::new(app.sketch_terrain().unwrap().to_vec()), app.settings().relief_m);
        src.generate(app.settings().seed, c, &crate::world::Neighbourhood::default()).heights
    });
    let far = app.world.coarse(c).expect("the nearest far tile");
    let n = COARSE_SAMPLES;
    assert!((0..n * n).all(|k| far[k] == full[(k / n) * 4 * crate::grid::TILE_SAMPLES + (k % n) * 4]));
    eprintln!("far tile {c:?}: {} of {} samples above 0 m", far.iter().filter(|&&v| v > 0.0).count(), n * n);
}

/// Choosing another world in the settings drops the weights hash a link gave the world it
/// opened: the sketch generator's weights are not compared with the learned world's (no
/// "this link was made with other weights" note), while a sketch link made with other
/// sketch weights still gets one.
#[test]
fn choosing_the_sketch_world_after_a_learned_link_gives_no_weights_note() {
    let mut app = TerrainApp::new(ShareState { weights: Some("0ld".into()), ..ShareState::default() });
    assert_eq!(app.set_learned(LearnedStatus::Ready { hash: "0ld".into() }), None);
    app.apply_settings(ShareState { source: SourceKind::Sketch, ..app.share_state() });
    assert_eq!(app.set_sketch_models(LearnedStatus::Ready { hash: "5ketch".into() }), None);
    let mut linked = TerrainApp::new(ShareState { source: SourceKind::Sketch, weights: Some("0ld".into()), ..ShareState::default() });
    assert!(linked.set_sketch_models(LearnedStatus::Ready { hash: "5ketch".into() }).is_some());
}
