//! The off-screen wgpu compute renderer: the CT volume as a 16-bit (f16) 3D texture uploaded
//! once per volume and sampled with the texture unit's trilinear filter, a ray-march shader
//! for the background and a tile-binned chord shader for the layers, both mirroring the CPU
//! reference sample for sample in f32.

use std::sync::Arc;

use nalgebra::{Point3, Vector3};
use wgpu::util::DeviceExt;

use crate::error::{Result, XrayError};
use crate::geometry::CArm;
use crate::layers::{Layers, TileBins};
use crate::render::{
    BACKGROUND_CHANNELS, LAYER_CHANNELS, MarchSettings, PathImage, Renderer, TILE_PX,
};
use crate::volume::{AirBricks, Volume};

/// Environment variable that turns "no GPU adapter" from a skipped test into a failure.
pub const REQUIRE_GPU_ENV: &str = "CATHLAB_REQUIRE_GPU";

struct UploadedVolume {
    volume: Arc<Volume>,
    view: wgpu::TextureView,
    air_view: wgpu::TextureView,
    bytes: usize,
}

/// HU as f16 bits: exact for |HU| ≤ 2048, within 1 HU up to 4096.
fn to_f16_bits(hu: &[i16]) -> Vec<u16> {
    hu.iter()
        .map(|&v| half::f16::from_f32(f32::from(v)).to_bits())
        .collect()
}

/// The wgpu renderer. One device and queue; the last volume stays uploaded.
pub struct GpuRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    /// Whether the adapter is a CPU (software) rasterizer.
    software: bool,
    march: wgpu::ComputePipeline,
    layers: wgpu::ComputePipeline,
    sampler: wgpu::Sampler,
    uploaded: Option<UploadedVolume>,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MarchParams {
    source: [f32; 4],
    corner: [f32; 4],
    step_u: [f32; 4],
    step_v: [f32; 4],
    m: [[f32; 4]; 3],
    source_index: [f32; 4],
    dims: [u32; 4],
    size: [u32; 4],
    settings: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct LayerParams {
    source: [f32; 4],
    corner: [f32; 4],
    step_u: [f32; 4],
    step_v: [f32; 4],
    size: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GpuPiece {
    start: [f32; 4],
    end: [f32; 4],
    radii: [f32; 4],
    start_cap: [f32; 4],
    end_cap: [f32; 4],
    pixel_box: [i32; 4],
}

fn v4(v: &Vector3<f64>, w: f32) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, w]
}

/// The pose's ray grid relative to the isocenter, with the detector grid scaled back onto
/// the isocenter plane: the rays are the same lines, but their points near the patient are
/// small numbers, so that f32 keeps 10 nm detail there.
fn grid_params(carm: &CArm) -> [[f32; 4]; 4] {
    let grid = carm.ray_grid();
    let sod_over_sid = carm.source_to_isocenter_m / carm.source_to_image_m;
    let source = grid.source.coords - carm.isocenter_m;
    let corner = source + (grid.corner.coords - grid.source.coords) * sod_over_sid;
    [
        v4(&source, 0.0),
        v4(&corner, 0.0),
        v4(&(grid.step_u * sod_over_sid), 0.0),
        v4(&(grid.step_v * sod_over_sid), 0.0),
    ]
}

impl GpuRenderer {
    /// Opens the first adapter wgpu finds (on CI: lavapipe, pinned by `VK_DRIVER_FILES`);
    /// [`XrayError::Gpu`] when there is none.
    pub fn new() -> Result<Self> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            ..Default::default()
        }))
        .map_err(|e| XrayError::Gpu(format!("no adapter: {e}")))?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("cathlab-xray"),
            required_limits: wgpu::Limits {
                max_storage_buffer_binding_size: limits.max_storage_buffer_binding_size,
                max_buffer_size: limits.max_buffer_size,
                max_texture_dimension_3d: limits.max_texture_dimension_3d,
                ..wgpu::Limits::downlevel_defaults()
            },
            ..Default::default()
        }))
        .map_err(|e| XrayError::Gpu(format!("device request on {}: {e}", info.name)))?;
        let pipeline = |source: &str, label: &str| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some("main"),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let march = pipeline(include_str!("shaders/march.wgsl"), "march");
        let layers = pipeline(include_str!("shaders/layers.wgsl"), "layers");
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("trilinear"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        Ok(Self {
            device,
            queue,
            adapter: format!("{} ({:?})", info.name, info.backend),
            software: info.device_type == wgpu::DeviceType::Cpu,
            march,
            layers,
            sampler,
            uploaded: None,
        })
    }

    /// Whether the adapter is a software rasterizer on the CPU (lavapipe, llvmpipe, WARP):
    /// there the CPU renderer shares the cores without the upload and read-back.
    pub fn is_software(&self) -> bool {
        self.software
    }

    /// The renderer if an adapter exists; `None` (with the reason on stderr) when none does
    /// and [`REQUIRE_GPU_ENV`] is unset. With it set, a missing adapter is an error.
    pub fn if_available() -> Result<Option<Self>> {
        match Self::new() {
            Ok(r) => Ok(Some(r)),
            Err(e) if std::env::var_os(REQUIRE_GPU_ENV).is_none() => {
                eprintln!(
                    "cathlab-xray: no GPU renderer ({e}); set {REQUIRE_GPU_ENV} to require one"
                );
                Ok(None)
            }
            Err(e) => Err(e),
        }
    }

    /// A 3D texture of `format` holding `data` (tightly packed, `texel_bytes` per texel).
    fn texture_3d(
        &self,
        label: &str,
        dims: [u32; 3],
        format: wgpu::TextureFormat,
        texel_bytes: u32,
        data: &[u8],
    ) -> wgpu::TextureView {
        let size = wgpu::Extent3d {
            width: dims[0],
            height: dims[1],
            depth_or_array_layers: dims[2],
        };
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        self.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            data,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(texel_bytes * dims[0]),
                rows_per_image: Some(dims[1]),
            },
            size,
        );
        texture.create_view(&Default::default())
    }

    fn upload(&mut self, volume: &Arc<Volume>) -> Result<(wgpu::TextureView, wgpu::TextureView)> {
        let cached = self
            .uploaded
            .as_ref()
            .is_some_and(|u| Arc::ptr_eq(&u.volume, volume));
        if !cached {
            self.uploaded = None;
            let [nx, ny, nz] = volume.dims.map(|n| n as u32);
            let max = self.device.limits().max_texture_dimension_3d;
            if nx.max(ny).max(nz) > max {
                return Err(XrayError::Gpu(format!(
                    "volume {nx}×{ny}×{nz} exceeds the adapter's 3D texture limit {max}"
                )));
            }
            let view = self.texture_3d(
                "ct volume (HU as f16)",
                [nx, ny, nz],
                wgpu::TextureFormat::R16Float,
                2,
                bytemuck::cast_slice(&to_f16_bits(&volume.hu)),
            );
            let bricks = AirBricks::of(volume);
            let air_view = self.texture_3d(
                "air bricks",
                bricks.dims.map(|n| n as u32),
                wgpu::TextureFormat::R8Uint,
                1,
                &bricks.air,
            );
            self.uploaded = Some(UploadedVolume {
                volume: Arc::clone(volume),
                view,
                air_view,
                bytes: volume.hu.len() * 2 + bricks.air.len(),
            });
        }
        let uploaded = self.uploaded.as_ref().expect("just uploaded");
        Ok((uploaded.view.clone(), uploaded.air_view.clone()))
    }

    /// Runs `pipeline` over a width × height grid with the given bindings and reads back
    /// `planes` f32 planes.
    fn dispatch(
        &self,
        pipeline: &wgpu::ComputePipeline,
        resources: &[wgpu::BindingResource<'_>],
        width: u32,
        height: u32,
        planes: usize,
    ) -> Result<Vec<Vec<f32>>> {
        let count = (width * height) as usize;
        let bytes = (count * planes * 4) as u64;
        let output = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("paths"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("paths readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut entries: Vec<wgpu::BindGroupEntry<'_>> = resources
            .iter()
            .enumerate()
            .map(|(i, r)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: r.clone(),
            })
            .collect();
        entries.push(wgpu::BindGroupEntry {
            binding: resources.len() as u32,
            resource: output.as_entire_binding(),
        });
        let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(width.div_ceil(8), height.div_ceil(8), 1);
        }
        encoder.copy_buffer_to_buffer(&output, 0, &readback, 0, bytes);
        self.queue.submit([encoder.finish()]);
        let slice = readback.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| XrayError::Gpu(format!("poll: {e}")))?;
        rx.recv()
            .map_err(|e| XrayError::Gpu(format!("map callback dropped: {e}")))?
            .map_err(|e| XrayError::Gpu(format!("map: {e}")))?;
        let data = slice
            .get_mapped_range()
            .map_err(|e| XrayError::Gpu(format!("mapped range: {e}")))?;
        let all: &[f32] = bytemuck::cast_slice(&data);
        let out = all.chunks_exact(count).map(<[f32]>::to_vec).collect();
        drop(data);
        readback.unmap();
        Ok(out)
    }
}

impl Renderer for GpuRenderer {
    fn name(&self) -> String {
        format!("wgpu ({})", self.adapter)
    }

    fn project_volume(
        &mut self,
        volume: &Arc<Volume>,
        carm: &CArm,
        settings: &MarchSettings,
    ) -> Result<PathImage> {
        carm.validate()?;
        settings.validate()?;
        let (w, h) = (carm.detector.width_px, carm.detector.height_px);
        let (m, offset) = volume.index_transform();
        let source_index = m * carm.source().coords + offset;
        let [source, corner, step_u, step_v] = grid_params(carm);
        let params = MarchParams {
            source,
            corner,
            step_u,
            step_v,
            m: [
                v4(&m.column(0).into(), 0.0),
                v4(&m.column(1).into(), 0.0),
                v4(&m.column(2).into(), 0.0),
            ],
            source_index: v4(&source_index, 0.0),
            dims: [volume.dims[0], volume.dims[1], volume.dims[2], 0].map(|n| n as u32),
            size: [w, h, 0, 0],
            settings: [
                (settings.step_voxels * volume.min_spacing_m()) as f32,
                settings.hu_model.bone_hu as f32,
                0.0,
                0.0,
            ],
        };
        let uniform = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("march params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        let (view, air_view) = self.upload(volume)?;
        let planes = self.dispatch(
            &self.march,
            &[
                uniform.as_entire_binding(),
                wgpu::BindingResource::TextureView(&view),
                wgpu::BindingResource::Sampler(&self.sampler),
                wgpu::BindingResource::TextureView(&air_view),
            ],
            w,
            h,
            BACKGROUND_CHANNELS,
        )?;
        Ok(PathImage {
            width: w,
            height: h,
            channels: planes,
        })
    }

    fn project_layers(&mut self, layers: &Layers, carm: &CArm) -> Result<PathImage> {
        carm.validate()?;
        let (w, h) = (carm.detector.width_px, carm.detector.height_px);
        if layers.pieces().is_empty() {
            return Ok(PathImage::zeros(w, h, LAYER_CHANNELS));
        }
        let bins = TileBins::build(layers, carm, TILE_PX);
        let rel = |p: &Point3<f64>| p.coords - carm.isocenter_m;
        let pieces: Vec<GpuPiece> = layers
            .pieces()
            .iter()
            .zip(&bins.boxes)
            .map(|(p, b)| GpuPiece {
                start: v4(&rel(&p.start), p.density as f32),
                end: v4(&rel(&p.end), p.material.channel() as f32),
                radii: [
                    p.outer_radius_m[0] as f32,
                    p.outer_radius_m[1] as f32,
                    p.inner_radius_m[0] as f32,
                    p.inner_radius_m[1] as f32,
                ],
                start_cap: v4(&p.start_cap, 0.0),
                end_cap: v4(&p.end_cap, 0.0),
                pixel_box: *b,
            })
            .collect();
        let [source, corner, step_u, step_v] = grid_params(carm);
        let params = LayerParams {
            source,
            corner,
            step_u,
            step_v,
            size: [w, h, bins.tile_px, bins.tiles[0]],
        };
        let buffer = |label: &str, contents: &[u8], usage| {
            self.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents,
                    usage,
                })
        };
        let uniform = buffer(
            "layer params",
            bytemuck::bytes_of(&params),
            wgpu::BufferUsages::UNIFORM,
        );
        let storage = wgpu::BufferUsages::STORAGE;
        let pieces = buffer("pieces", bytemuck::cast_slice(&pieces), storage);
        let offsets = buffer("tile offsets", bytemuck::cast_slice(&bins.offsets), storage);
        // Storage buffers may not be empty.
        let indices: &[u32] = if bins.indices.is_empty() {
            &[0]
        } else {
            &bins.indices
        };
        let indices = buffer("tile indices", bytemuck::cast_slice(indices), storage);
        let planes = self.dispatch(
            &self.layers,
            &[
                uniform.as_entire_binding(),
                pieces.as_entire_binding(),
                offsets.as_entire_binding(),
                indices.as_entire_binding(),
            ],
            w,
            h,
            LAYER_CHANNELS,
        )?;
        Ok(PathImage {
            width: w,
            height: h,
            channels: planes,
        })
    }

    fn device_memory_bytes(&self) -> usize {
        self.uploaded.as_ref().map_or(0, |u| u.bytes)
    }
}
