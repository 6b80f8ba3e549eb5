//! The wgpu renderer: draws the selected quadtree nodes, the sky and the water into an
//! offscreen colour target (which the UI shows), with reverse-Z depth.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use wgpu::util::DeviceExt;

use super::MESH_BYTES;
use super::camera::Camera;
use super::mesh::{NODE_VERTICES, Vertex, node_indices_strided, node_vertices};
use super::resident::{ResidentMeshes, Slots};
use super::shadow::{CASCADES, SHADOW_MAP_PX, cascades};
use crate::world::quadtree::{DRAW_STRIDES, NodeData};

/// Colour format of the offscreen target where the GPU encodes sRGB ([`TargetEncoding::Gpu`]):
/// the shaders write linear values, stored sRGB.
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// The colour target's format as the UI samples it: the same bytes, not decoded from sRGB (and
/// the target's own format where the shaders encode, [`TargetEncoding::Shader`]).
pub const SHOWN_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// Who turns the shaders' linear colours into the sRGB-encoded bytes of the 3-D view's target.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TargetEncoding {
    /// The GPU: an sRGB target ([`COLOR_FORMAT`]), which the UI reads through a plain 8-bit
    /// view of the same texels ([`SHOWN_FORMAT`]). Needs view formats (WebGPU, Vulkan).
    Gpu,
    /// The fragment shaders (the `ENCODE_SRGB` override): a plain 8-bit target holding the
    /// same bytes. For devices without view formats (WebGL2, OpenGL ES), where a texture is
    /// read in its own format only. Water is blended in encoded values there.
    Shader,
}

impl TargetEncoding {
    /// The encoding `adapter` allows: [`Self::Gpu`] where it has view formats.
    pub fn for_adapter(adapter: &wgpu::Adapter) -> Self {
        if adapter.get_downlevel_capabilities().flags.contains(wgpu::DownlevelFlags::VIEW_FORMATS) { Self::Gpu } else { Self::Shader }
    }

    /// The target's format, and the other formats it is viewed in ([`SHOWN_FORMAT`] for the UI).
    fn formats(self) -> (wgpu::TextureFormat, &'static [wgpu::TextureFormat]) {
        match self {
            Self::Gpu => (COLOR_FORMAT, &[SHOWN_FORMAT]),
            Self::Shader => (SHOWN_FORMAT, &[]),
        }
    }

    /// The fragment shaders' pipeline constants.
    fn constants(self) -> &'static [(&'static str, f64)] {
        match self {
            Self::Gpu => &[],
            Self::Shader => &[("ENCODE_SRGB", 1.0)],
        }
    }
}
/// Depth format (reverse-Z: 1 at the near plane, 0 at infinity).
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

const COMMON_WGSL: &str = include_str!("../../shaders/common.wgsl");
const SKY_WGSL: &str = include_str!("../../shaders/sky.wgsl");
const TERRAIN_WGSL: &str = include_str!("../../shaders/terrain.wgsl");
const WATER_WGSL: &str = include_str!("../../shaders/water.wgsl");
const SHADOW_WGSL: &str = include_str!("../../shaders/shadow.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Globals {
    view_proj: [[f32; 4]; 4],
    inv_view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    sun: [f32; 4],
    fog: [f32; 4],
    params: [f32; 4],
    shadow: [[[f32; 4]; 4]; CASCADES],
    shadow_info: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Instance {
    offset: [f32; 3],
    depth: f32,
}

/// Everything about a frame that is not geometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameParams {
    /// The camera.
    pub camera: Camera,
    /// Target size (pixels).
    pub size: [u32; 2],
    /// Unit vector towards the sun.
    pub sun_dir: Vec3,
    /// Distance where fog starts (metres).
    pub fog_start_m: f32,
    /// Distance where fog is complete (metres).
    pub fog_end_m: f32,
    /// Height of the water plane (metres).
    pub water_level_m: f32,
    /// Terrain height range, for colouring by elevation (metres).
    pub amplitude_m: f32,
    /// Tint nodes by quadtree depth.
    pub show_lod: bool,
    /// Seconds since start (animates the water).
    pub time_s: f32,
    /// Plain shading (colours by elevation and slope, no shadows or detail): for slow devices.
    pub plain_shading: bool,
}

/// Farthest distance from the eye (metres) that terrain shadows reach.
pub const SHADOW_FAR_M: f32 = 40_000.0;

/// What one frame drew.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RenderStats {
    /// Nodes drawn.
    pub nodes: usize,
    /// Node meshes uploaded this frame.
    pub uploads: usize,
    /// Triangles submitted.
    pub triangles: usize,
    /// Node meshes resident on the GPU.
    pub resident: usize,
    /// Nodes of the frame not drawn: more than the mesh buffer's slots on this device.
    pub over_budget: usize,
    /// Wall time (milliseconds) of the frame's uniform writes and mesh uploads.
    pub upload_ms: f64,
    /// Wall time (milliseconds) of encoding the pass and submitting it.
    pub submit_ms: f64,
}

struct Target {
    size: [u32; 2],
    /// Read back by [`TerrainRenderer::read_target`], natively only.
    #[cfg_attr(target_arch = "wasm32", allow(dead_code))]
    color_texture: wgpu::Texture,
    color: wgpu::TextureView,
    /// The same texels as plain 8-bit values: egui takes a user texture's values as sRGB-encoded
    /// (it samples without decoding), so it is shown through this view; through `color` it
    /// would see the decoded, linear values and show them too dark.
    shown: wgpu::TextureView,
    depth: wgpu::TextureView,
}

/// GPU state of the terrain renderer.
pub struct TerrainRenderer {
    globals: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    sky: wgpu::RenderPipeline,
    /// The terrain in the full shading.
    terrain: wgpu::RenderPipeline,
    /// The terrain in the plain shading.
    terrain_plain: wgpu::RenderPipeline,
    water: wgpu::RenderPipeline,
    /// Draws node meshes as depth from the sun into one shadow cascade.
    shadow: wgpu::RenderPipeline,
    /// Each cascade's view-projection, and its bind group.
    cascade_uniforms: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    /// Each cascade's layer of the shadow map, as a render target.
    cascade_layers: Vec<wgpu::TextureView>,
    indices: wgpu::Buffer,
    /// The index ranges of each stride of [`DRAW_STRIDES`] in `indices`.
    index_ranges: Vec<(u8, std::ops::Range<u32>)>,
    instances: wgpu::Buffer,
    instance_capacity: usize,
    /// Each resident node's slot in `slab`.
    meshes: ResidentMeshes<u32>,
    slots: Slots,
    /// All node meshes, [`NODE_VERTICES`] vertices per slot.
    slab: wgpu::Buffer,
    /// Most slots the mesh buffer may have on this device.
    slot_limit: u32,
    encoding: TargetEncoding,
    target: Option<Target>,
}

/// Slots the mesh buffer starts with (it doubles when full, up to [`super::mesh_slots`]).
const FIRST_SLOTS: u32 = 64;
const _: () = assert!(MESH_BYTES.is_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT));

impl TerrainRenderer {
    /// Creates pipelines and shared buffers on `device`, whose view target is encoded as
    /// `encoding` says ([`TargetEncoding::for_adapter`]).
    pub fn new(device: &wgpu::Device, encoding: TargetEncoding) -> Self {
        let uniform_entry = |visibility| wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility,
            ty: wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Uniform, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("terrain globals"),
            entries: &[
                uniform_entry(wgpu::ShaderStages::VERTEX_FRAGMENT),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture { sample_type: wgpu::TextureSampleType::Depth, view_dimension: wgpu::TextureViewDimension::D2Array, multisampled: false },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
                    count: None,
                },
            ],
        });
        let globals = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("terrain globals"),
            size: std::mem::size_of::<Globals>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let shadow_map = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("shadow cascades"),
            size: wgpu::Extent3d { width: SHADOW_MAP_PX, height: SHADOW_MAP_PX, depth_or_array_layers: CASCADES as u32 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let cascade_layers = (0..CASCADES as u32)
            .map(|layer| {
                shadow_map.create_view(&wgpu::TextureViewDescriptor {
                    label: Some("shadow cascade"),
                    dimension: Some(wgpu::TextureViewDimension::D2),
                    base_array_layer: layer,
                    array_layer_count: Some(1),
                    ..Default::default()
                })
            })
            .collect();
        let shadow_view = shadow_map.create_view(&wgpu::TextureViewDescriptor { dimension: Some(wgpu::TextureViewDimension::D2Array), ..Default::default() });
        let shadow_sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow compare"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(wgpu::CompareFunction::LessEqual),
            ..Default::default()
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("terrain globals"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: globals.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&shadow_view) },
                wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::Sampler(&shadow_sampler) },
            ],
        });
        let cascade_layout =
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("shadow cascade"), entries: &[uniform_entry(wgpu::ShaderStages::VERTEX)] });
        let cascade_uniforms = (0..CASCADES)
            .map(|_| {
                let buffer = device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("shadow cascade"),
                    size: 64,
                    usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
                let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("shadow cascade"),
                    layout: &cascade_layout,
                    entries: &[wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() }],
                });
                (buffer, group)
            })
            .collect();
        let (target_format, _) = encoding.formats();
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor { label: Some("terrain"), bind_group_layouts: &[Some(&layout)], immediate_size: 0 });
        let module = |name: &str, src: &str| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor { label: Some(name), source: wgpu::ShaderSource::Wgsl(format!("{COMMON_WGSL}\n{src}").into()) })
        };
        let pipeline = |name: &str,
                        src: &str,
                        fs: &str,
                        buffers: &[Option<wgpu::VertexBufferLayout<'_>>],
                        depth_write: bool,
                        compare: wgpu::CompareFunction,
                        blend: Option<wgpu::BlendState>| {
            let m = module(name, src);
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(name),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState { module: &m, entry_point: Some("vs_main"), compilation_options: Default::default(), buffers },
                primitive: wgpu::PrimitiveState { topology: wgpu::PrimitiveTopology::TriangleList, cull_mode: None, ..Default::default() },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(depth_write),
                    depth_compare: Some(compare),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &m,
                    entry_point: Some(fs),
                    compilation_options: wgpu::PipelineCompilationOptions { constants: encoding.constants(), ..Default::default() },
                    targets: &[Some(wgpu::ColorTargetState { format: target_format, blend, write_mask: wgpu::ColorWrites::ALL })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let vertex_layout = wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3],
        };
        let instance_layout = wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Instance>() as u64,
            step_mode: wgpu::VertexStepMode::Instance,
            attributes: &wgpu::vertex_attr_array![2 => Float32x3, 3 => Float32],
        };
        let sky = pipeline("sky", SKY_WGSL, "fs_main", &[], false, wgpu::CompareFunction::Always, None);
        let terrain_buffers = [Some(vertex_layout.clone()), Some(instance_layout.clone())];
        let terrain = pipeline("terrain", TERRAIN_WGSL, "fs_full", &terrain_buffers, true, wgpu::CompareFunction::Greater, None);
        let terrain_plain = pipeline("terrain plain", TERRAIN_WGSL, "fs_plain", &terrain_buffers, true, wgpu::CompareFunction::Greater, None);
        let water = pipeline("water", WATER_WGSL, "fs_main", &[], true, wgpu::CompareFunction::Greater, Some(wgpu::BlendState::ALPHA_BLENDING));
        let shadow_module = device.create_shader_module(wgpu::ShaderModuleDescriptor { label: Some("shadow"), source: wgpu::ShaderSource::Wgsl(SHADOW_WGSL.into()) });
        let shadow_layout =
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor { label: Some("shadow"), bind_group_layouts: &[Some(&cascade_layout)], immediate_size: 0 });
        let shadow = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("shadow"),
            layout: Some(&shadow_layout),
            vertex: wgpu::VertexState {
                module: &shadow_module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[Some(vertex_layout.clone()), Some(instance_layout.clone())],
            },
            primitive: wgpu::PrimitiveState { topology: wgpu::PrimitiveTopology::TriangleList, cull_mode: None, ..Default::default() },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: wgpu::DepthBiasState { constant: 0, slope_scale: 1.5, clamp: 0.0 },
            }),
            multisample: Default::default(),
            fragment: None,
            multiview_mask: None,
            cache: None,
        });
        let mut idx = Vec::new();
        let mut index_ranges = Vec::new();
        for stride in DRAW_STRIDES {
            let start = idx.len() as u32;
            idx.extend(node_indices_strided(stride as usize));
            index_ranges.push((stride, start..idx.len() as u32));
        }
        let indices =
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some("node indices"), contents: bytemuck::cast_slice(&idx), usage: wgpu::BufferUsages::INDEX });
        let instance_capacity = 256;
        let instances = Self::instance_buffer(device, instance_capacity);
        let mut slots = Slots::default();
        slots.grow(FIRST_SLOTS);
        let slab = Self::slab_buffer(device, FIRST_SLOTS);
        Self {
            globals,
            bind_group,
            sky,
            terrain,
            terrain_plain,
            water,
            shadow,
            cascade_uniforms,
            cascade_layers,
            indices,
            index_ranges,
            instances,
            instance_capacity,
            meshes: ResidentMeshes::default(),
            slots,
            slab,
            slot_limit: super::mesh_slots(device.limits().max_buffer_size).max(FIRST_SLOTS),
            encoding,
            target: None,
        }
    }

    fn slab_buffer(device: &wgpu::Device, slots: u32) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("node meshes"),
            size: slots as u64 * MESH_BYTES,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        })
    }

    fn instance_buffer(device: &wgpu::Device, n: usize) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("node instances"),
            size: (n * std::mem::size_of::<Instance>()) as u64,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Makes sure the offscreen target has `size` pixels; returns true if it was (re)created,
    /// in which case the view from `color_view` changed.
    pub fn ensure_target(&mut self, device: &wgpu::Device, size: [u32; 2]) -> bool {
        let size = [size[0].max(1), size[1].max(1)];
        if self.target.as_ref().is_some_and(|t| t.size == size) {
            return false;
        }
        let make = |format, usage, label, view_formats: &[wgpu::TextureFormat]| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats,
            })
        };
        let color_usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_SRC;
        let (format, view_formats) = self.encoding.formats();
        let color_texture = make(format, color_usage, "terrain colour", view_formats);
        self.target = Some(Target {
            size,
            color: color_texture.create_view(&Default::default()),
            shown: color_texture.create_view(&wgpu::TextureViewDescriptor { format: Some(SHOWN_FORMAT), ..Default::default() }),
            color_texture,
            depth: make(DEPTH_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT, "terrain depth", &[]).create_view(&Default::default()),
        });
        true
    }

    /// The offscreen colour target as the UI shows it (after `ensure_target`): its sRGB-encoded
    /// values, read without decoding.
    pub fn color_view(&self) -> Option<&wgpu::TextureView> {
        self.target.as_ref().map(|t| &t.shown)
    }

    /// The offscreen target's pixels after the work submitted so far: `width × height` RGBA
    /// values (sRGB, 8 bits each), rows top to bottom. Blocks until the GPU is done (native
    /// only: a browser cannot wait on its GPU).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn read_target(&self, device: &wgpu::Device, queue: &wgpu::Queue) -> Result<(u32, u32, Vec<u8>), String> {
        let t = self.target.as_ref().ok_or("nothing drawn yet")?;
        let [w, h] = t.size;
        let row = (w * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read terrain colour"),
            size: (row * h) as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("read terrain colour") });
        enc.copy_texture_to_buffer(
            t.color_texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo { buffer: &buffer, layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(row), rows_per_image: Some(h) } },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        queue.submit([enc.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        buffer.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        device.poll(wgpu::PollType::Wait { submission_index: None, timeout: None }).map_err(|e| format!("waiting for the GPU: {e}"))?;
        rx.recv().map_err(|e| e.to_string())?.map_err(|e| format!("reading the picture back: {e}"))?;
        let mapped = buffer.slice(..).get_mapped_range().map_err(|e| format!("reading the picture back: {e:?}"))?;
        let mut out = Vec::with_capacity((w * h * 4) as usize);
        for r in 0..h as usize {
            out.extend_from_slice(&mapped[r * row as usize..][..w as usize * 4]);
        }
        Ok((w, h, out))
    }

    /// Draws `nodes` for `params` into the offscreen target and submits the work. Node meshes
    /// are uploaded on first use and kept while drawn; meshes unused for `keep_frames` frames
    /// are dropped.
    pub fn render(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, nodes: &[Arc<NodeData>], params: &FrameParams, keep_frames: u64) -> RenderStats {
        self.ensure_target(device, params.size);
        let mut stats = RenderStats { nodes: nodes.len(), ..Default::default() };
        let cam = &params.camera;
        let aspect = params.size[0].max(1) as f32 / params.size[1].max(1) as f32;
        let vp = cam.view_proj(aspect);
        let sun = params.sun_dir.normalize();
        let shadow_far_m = params.fog_end_m.min(SHADOW_FAR_M);
        let cs = cascades(cam, aspect, sun, shadow_far_m);
        let g = Globals {
            view_proj: vp.to_cols_array_2d(),
            inv_view_proj: vp.inverse().to_cols_array_2d(),
            eye: [cam.position_m.x as f32, cam.position_m.y as f32, cam.position_m.z as f32, 0.0],
            sun: sun.extend(0.0).to_array(),
            fog: [params.fog_start_m, params.fog_end_m, params.water_level_m, params.amplitude_m],
            params: [if params.show_lod { 1.0 } else { 0.0 }, params.time_s, if params.plain_shading { 0.0 } else { 1.0 }, 0.0],
            shadow: cs.map(|c| c.view_proj.to_cols_array_2d()),
            shadow_info: [cs[0].far_m, cs[1].far_m, cs[0].texel_m, cs[1].texel_m],
        };
        let t0 = web_time::Instant::now();
        queue.write_buffer(&self.globals, 0, bytemuck::bytes_of(&g));
        if !params.plain_shading {
            for (c, (buffer, _)) in cs.iter().zip(&self.cascade_uniforms) {
                queue.write_buffer(buffer, 0, bytemuck::cast_slice(&c.view_proj.to_cols_array()));
            }
        }

        // Never more nodes than the device's mesh buffer can hold (the app keeps its view
        // within half of that by raising its LOD target).
        let drawn = nodes.len().min(self.slot_limit as usize);
        stats.over_budget = nodes.len() - drawn;
        let nodes = &nodes[..drawn];
        let mut inst = Vec::with_capacity(nodes.len());
        // Room for every node of this frame, should all be new: the mesh buffer doubles (its
        // contents copied on the GPU) when needed, up to the limit; at the limit, meshes of
        // nodes not in this frame leave first.
        let capacity = self.slots.capacity_for(nodes.len() as u32, FIRST_SLOTS).min(self.slot_limit);
        if self.slots.in_use() as usize + nodes.len() > capacity as usize {
            let ids: std::collections::HashSet<_> = nodes.iter().map(|n| n.id).collect();
            for slot in self.meshes.evict_unless(|id| ids.contains(id)) {
                self.slots.give(slot);
            }
        }
        if capacity > self.slots.capacity() {
            let slab = Self::slab_buffer(device, capacity);
            let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("grow node meshes") });
            enc.copy_buffer_to_buffer(&self.slab, 0, &slab, 0, self.slots.capacity() as u64 * MESH_BYTES);
            queue.submit([enc.finish()]);
            self.slab = slab;
            self.slots.grow(capacity);
        }
        self.meshes.begin_frame();
        for n in nodes {
            let (slots, slab) = (&mut self.slots, &self.slab);
            let uploaded = self.meshes.use_mesh(n.id, n.version, |old| {
                // One buffer for all meshes, written with queued writes: a buffer per mesh
                // (and worse, one mapped at creation) costs a round trip to the browser's GPU
                // process each (7–9 ms on SwiftShader, measured in the page).
                let slot = old.or_else(|| slots.take()).expect("room made above");
                queue.write_buffer(slab, slot as u64 * MESH_BYTES, bytemuck::cast_slice(&node_vertices(n)));
                slot
            });
            stats.uploads += uploaded as usize;
            let (x, z) = n.id.origin_m();
            inst.push(Instance { offset: [(x - cam.position_m.x) as f32, -cam.position_m.y as f32, (z - cam.position_m.z) as f32], depth: n.id.depth as f32 });
        }
        if inst.len() > self.instance_capacity {
            self.instance_capacity = inst.len().next_power_of_two();
            self.instances = Self::instance_buffer(device, self.instance_capacity);
        }
        if !inst.is_empty() {
            queue.write_buffer(&self.instances, 0, bytemuck::cast_slice(&inst));
        }
        for slot in self.meshes.evict_unused(keep_frames) {
            self.slots.give(slot);
        }
        stats.resident = self.meshes.len();

        stats.upload_ms = t0.elapsed().as_secs_f64() * 1e3;
        let t1 = web_time::Instant::now();
        let target = self.target.as_ref().expect("target ensured above");
        let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("terrain") });
        // The shadow cascades: every drawn node at the coarsest stride (a quarter of its
        // vertices per side: the shapes that cast shadows over tens of metres and more).
        let coarsest = DRAW_STRIDES[DRAW_STRIDES.len() - 1];
        for (layer, (_, group)) in self.cascade_layers.iter().zip(&self.cascade_uniforms).take(if params.plain_shading { 0 } else { CASCADES }) {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("shadow cascade"),
                color_attachments: &[],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: layer,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.shadow);
            pass.set_bind_group(0, group, &[]);
            self.draw_nodes(&mut pass, nodes, |_| coarsest);
        }
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("terrain"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &target.color,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::BLACK), store: wgpu::StoreOp::Store },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &target.depth,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(0.0), store: wgpu::StoreOp::Discard }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.set_pipeline(&self.sky);
            pass.draw(0..3, 0..1);
            pass.set_pipeline(if params.plain_shading { &self.terrain_plain } else { &self.terrain });
            stats.triangles = self.draw_nodes(&mut pass, nodes, |n| n.stride);
            pass.set_pipeline(&self.water);
            pass.draw(0..6, 0..1);
        }
        queue.submit([enc.finish()]);
        stats.submit_ms = t1.elapsed().as_secs_f64() * 1e3;
        stats
    }
}

impl TerrainRenderer {
    /// Draws each of `nodes` whose mesh is resident (node `k` with instance `k`) at the index
    /// stride `stride` gives it (the first of [`DRAW_STRIDES`] for one not among them), in a
    /// pass whose pipeline and bind group are set. Returns the triangles drawn.
    ///
    /// Each draw binds its node's slot of the mesh buffer and its instance at their offsets
    /// rather than passing a base vertex and a first instance, which WebGL2 does not have.
    fn draw_nodes(&self, pass: &mut wgpu::RenderPass<'_>, nodes: &[Arc<NodeData>], stride: impl Fn(&NodeData) -> u8) -> usize {
        const VERTEX_BYTES: u64 = std::mem::size_of::<Vertex>() as u64;
        const INSTANCE_BYTES: u64 = std::mem::size_of::<Instance>() as u64;
        pass.set_index_buffer(self.indices.slice(..), wgpu::IndexFormat::Uint16);
        let mut triangles = 0;
        for (k, n) in nodes.iter().enumerate() {
            let want = stride(n);
            let range = self.index_ranges.iter().find(|(s, _)| *s == want).map_or(self.index_ranges[0].1.clone(), |(_, r)| r.clone());
            if let Some(&slot) = self.meshes.get(&n.id) {
                triangles += range.len() / 3;
                let first_vertex = slot as u64 * NODE_VERTICES as u64 * VERTEX_BYTES;
                pass.set_vertex_buffer(0, self.slab.slice(first_vertex..first_vertex + NODE_VERTICES as u64 * VERTEX_BYTES));
                pass.set_vertex_buffer(1, self.instances.slice(k as u64 * INSTANCE_BYTES..(k as u64 + 1) * INSTANCE_BYTES));
                pass.draw_indexed(range, 0, 0..1);
            }
        }
        triangles
    }
}

/// The sun direction for an azimuth and elevation (radians).
pub fn sun_direction(azimuth: f32, elevation: f32) -> Vec3 {
    let (se, ce) = elevation.sin_cos();
    let (sa, ca) = azimuth.sin_cos();
    Vec3::new(sa * ce, se, -ca * ce)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every render shader as the renderer builds it (the shared part first but for the shadow
    /// pass's, which stands alone), with the entry points its pipelines name.
    fn render_shaders() -> [(&'static str, String, &'static [&'static str]); 4] {
        let shared = |src: &str| format!("{COMMON_WGSL}\n{src}");
        [
            ("sky", shared(SKY_WGSL), &["vs_main", "fs_main"]),
            ("terrain", shared(TERRAIN_WGSL), &["vs_main", "fs_full", "fs_plain"]),
            ("water", shared(WATER_WGSL), &["vs_main", "fs_main"]),
            ("shadow", SHADOW_WGSL.to_string(), &["vs_main"]),
        ]
    }

    /// Every render shader, as the renderer builds it (the shared part first but for the shadow
    /// pass's, which stands alone), parses and
    /// passes naga's validation (the checks wgpu runs when it creates the module), and has
    /// the entry points the pipelines name (the shadow pass only a vertex stage, the terrain one
    /// fragment stage per shading).
    #[test]
    fn each_render_shader_parses_and_validates_with_its_entry_points() {
        for (name, code, want) in render_shaders() {
            let module = naga::front::wgsl::parse_str(&code).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&code)));
            naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::empty()).validate(&module).unwrap_or_else(|e| panic!("{name}: {e:?}"));
            let entries: Vec<&str> = module.entry_points.iter().map(|e| e.name.as_str()).collect();
            assert_eq!(entries, want, "{name}");
        }
    }

    /// Every entry point of every render shader, with the target encoded by the shaders
    /// (`ENCODE_SRGB` set, as on WebGL2) and without, translates to GLSL ES 3.00 as wgpu's
    /// WebGL2 backend translates it (overrides replaced first, clip space adjusted); the
    /// encoding changes each fragment stage's code and no vertex stage's (the shadow pass has
    /// no fragment stage and no override).
    #[test]
    fn each_render_shader_translates_to_glsl_es_300_for_webgl2() {
        use naga::back::glsl;
        for (name, code, _) in render_shaders() {
            let module = naga::front::wgsl::parse_str(&code).unwrap();
            let info = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::empty()).validate(&module).unwrap();
            let mut code_of = std::collections::HashMap::new();
            for encode in [false, true] {
                let overridden = encode && !module.overrides.is_empty();
                let constants: naga::back::PipelineConstants = if overridden { [("ENCODE_SRGB".to_string(), 1.0)].into_iter().collect() } else { Default::default() };
                for ep in &module.entry_points {
                    let (m, i) = naga::back::pipeline_constants::process_overrides(&module, &info, Some((ep.stage, &ep.name)), &constants)
                        .unwrap_or_else(|e| panic!("{name} {}: {e:?}", ep.name));
                    let options = glsl::Options { version: glsl::Version::new_gles(300), ..Default::default() };
                    let pipeline = glsl::PipelineOptions { shader_stage: ep.stage, entry_point: ep.name.clone(), multiview: None };
                    let mut out = String::new();
                    glsl::Writer::new(&mut out, &m, &i, &options, &pipeline, naga::proc::BoundsCheckPolicies::default())
                        .and_then(|mut w| w.write())
                        .unwrap_or_else(|e| panic!("{name} {} (encode {encode}): {e:?}", ep.name));
                    assert!(out.starts_with("#version 300 es"), "{name} {}", ep.name);
                    code_of.insert((ep.name.clone(), encode), out);
                }
            }
            for ep in &module.entry_points {
                let changed = code_of[&(ep.name.clone(), false)] != code_of[&(ep.name.clone(), true)];
                assert_eq!(changed, ep.stage == naga::ShaderStage::Fragment && !module.overrides.is_empty(), "{name} {}: changed by the encoding", ep.name);
            }
        }
    }
}
