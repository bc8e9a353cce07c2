//! The wgpu renderer: one device, one pipeline, the vehicle's and the scene's meshes, one
//! colour + depth target and readback buffer per camera.
//!
//! Per frame: forward kinematics of the vehicle (into a reused buffer), one write of every
//! object's transform and material into a uniform buffer (one aligned slot per object, bound
//! with a dynamic offset), one render pass per camera, one copy per camera into its readback
//! buffer, one submission, one wait. Nothing is allocated on the GPU per frame; on the CPU only
//! the output image (or nothing, with [`Renderer::render_into`]).

use std::sync::{Arc, Mutex};

use bytemuck::{Pod, Zeroable};
use nalgebra::{Isometry3, Matrix4};
use platform::{JointKind, KinematicModel, LinkId, Vehicle};
use sim_twin::SceneVisual;

use crate::appearance::{
    ARM_RGB, Appearance, BASE_RGB, GRIPPER_RGB, Lighting, Material, ROTOR_RGB, SKY_RGB, VisualDr,
};
use crate::camera::{CameraParent, CameraSpec};
use crate::error::RenderError;
use crate::image::Image;
use crate::mesh::{Mesh, Vertex};
use crate::snapshot::Snapshot;

const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// The camera uniform (shader.wgsl `Camera`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct CameraUniform {
    clip_from_world: [f32; 16],
    toward_light: [f32; 4],
    light: [f32; 4],
}

/// The object uniform (shader.wgsl `Object`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct ObjectUniform {
    world_from_object: [f32; 16],
    material: [[f32; 4]; 4],
}

/// Where one mesh lies in the shared vertex and index buffers.
#[derive(Debug, Clone, Copy)]
struct MeshRange {
    first_index: u32,
    index_count: u32,
    base_vertex: i32,
}

/// A set of meshes in one vertex buffer and one index buffer.
#[derive(Debug)]
struct GpuMeshes {
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    ranges: Vec<MeshRange>,
}

impl GpuMeshes {
    fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        label: &str,
        meshes: &[Mesh],
    ) -> Result<Self, RenderError> {
        let mut vertices: Vec<Vertex> = Vec::new();
        let mut indices: Vec<u32> = Vec::new();
        let mut ranges = Vec::with_capacity(meshes.len());
        let too_big = || RenderError::State(format!("{label}: more than 2³¹ vertices"));
        for m in meshes {
            ranges.push(MeshRange {
                first_index: u32::try_from(indices.len()).map_err(|_| too_big())?,
                index_count: u32::try_from(m.indices.len()).map_err(|_| too_big())?,
                base_vertex: i32::try_from(vertices.len()).map_err(|_| too_big())?,
            });
            vertices.extend_from_slice(&m.vertices);
            indices.extend_from_slice(&m.indices);
        }
        // wgpu refuses empty buffers: keep one degenerate vertex and triangle.
        if vertices.is_empty() {
            vertices.push(Vertex::zeroed());
            indices.extend_from_slice(&[0, 0, 0]);
        }
        let upload = |what: &str, bytes: &[u8], usage: wgpu::BufferUsages| {
            let b = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(&format!("{label} {what}")),
                size: bytes.len() as u64,
                usage: usage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            queue.write_buffer(&b, 0, bytes);
            b
        };
        Ok(Self {
            vertices: upload(
                "vertices",
                bytemuck::cast_slice(&vertices),
                wgpu::BufferUsages::VERTEX,
            ),
            indices: upload(
                "indices",
                bytemuck::cast_slice(&indices),
                wgpu::BufferUsages::INDEX,
            ),
            ranges,
        })
    }
}

/// One shape of the vehicle: its link, where it sits on it, its look.
#[derive(Debug, Clone)]
struct VehicleShape {
    link: LinkId,
    link_from_shape: Isometry3<f64>,
    material: Material,
}

/// A camera's targets and readback.
#[derive(Debug)]
struct CameraTarget {
    spec: CameraSpec,
    color: wgpu::Texture,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    readback: wgpu::Buffer,
    padded_bytes_per_row: u32,
    uniform: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    /// The readback's map result, set by wgpu's callback.
    mapped: Arc<Mutex<Option<Result<(), wgpu::BufferAsyncError>>>>,
}

/// The object slots: one uniform buffer, one bind group with a dynamic offset.
#[derive(Debug)]
struct ObjectSlots {
    buffer: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    capacity: usize,
    /// Bytes written each frame (reused).
    staging: Vec<u8>,
}

/// A headless renderer of a vehicle's cameras in a twin scene.
///
/// Build it once per vehicle ([`Renderer::new`]), give it the scene at every episode reset
/// ([`Renderer::reset_scene`]), then draw any camera at any state ([`Renderer::render`],
/// [`Renderer::render_set_into`] for several cameras of one tick in one submission).
#[derive(Debug)]
pub struct Renderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: wgpu::AdapterInfo,
    pipeline: wgpu::RenderPipeline,
    object_layout: wgpu::BindGroupLayout,
    slot_stride: u64,
    model: KinematicModel,
    dof: usize,
    vehicle_shapes: Vec<VehicleShape>,
    vehicle_meshes: GpuMeshes,
    scene_materials: Vec<Material>,
    scene_meshes: GpuMeshes,
    lighting: Lighting,
    dr: VisualDr,
    cameras: Vec<CameraTarget>,
    slots: ObjectSlots,
    /// Forward kinematics scratch: root_from_link per link.
    link_poses: Vec<Isometry3<f64>>,
    /// Cameras of the frame begun and not yet finished.
    in_flight: Vec<usize>,
}

/// The nominal colour of a vehicle link, by role (appearance.rs).
fn link_rgb(vehicle: &Vehicle, link: LinkId) -> [f32; 3] {
    let model = &vehicle.model;
    let rotor = vehicle
        .rotors
        .rotors
        .iter()
        .any(|r| model.link_id(&r.link) == Some(link));
    let finger = vehicle
        .gripper
        .as_ref()
        .is_some_and(|g| g.joints.iter().any(|&j| model.joints[j].child == link));
    let rigid_on_base = model
        .chain(link)
        .iter()
        .all(|&j| model.joints[j].kind == JointKind::Fixed);
    if rotor {
        ROTOR_RGB
    } else if finger || link == vehicle.ee_link {
        GRIPPER_RGB
    } else if rigid_on_base {
        BASE_RGB
    } else {
        ARM_RGB
    }
}

fn mat4_f32(m: &Matrix4<f64>) -> [f32; 16] {
    let mut out = [0.0f32; 16];
    for (o, v) in out.iter_mut().zip(m.as_slice()) {
        // Render precision: the GPU draws in f32.
        #[allow(clippy::cast_possible_truncation)]
        {
            *o = *v as f32;
        }
    }
    out
}

impl Renderer {
    /// A renderer of `cameras` on `vehicle`, on the first adapter wgpu offers (a GPU when
    /// present, else a software rasteriser such as Mesa's llvmpipe). `dr` sets whether
    /// [`Self::reset_scene`] randomises the look.
    pub fn new(
        vehicle: &Vehicle,
        cameras: &[CameraSpec],
        dr: VisualDr,
    ) -> Result<Self, RenderError> {
        for c in cameras {
            c.validate()?;
            if let CameraParent::Link(l) = c.parent
                && l >= vehicle.model.links.len()
            {
                return Err(RenderError::Camera {
                    name: c.name.clone(),
                    message: format!("parent link {l} is not a link of '{}'", vehicle.id),
                });
            }
        }
        let (device, queue, adapter) = pollster::block_on(open_device())?;
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("amstack render shader"),
            source: wgpu::ShaderSource::Wgsl(include_str!("shader.wgsl").into()),
        });
        let camera_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("camera"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: wgpu::BufferSize::new(size_of::<CameraUniform>() as u64),
                },
                count: None,
            }],
        });
        let object_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("object"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: true,
                    min_binding_size: wgpu::BufferSize::new(size_of::<ObjectUniform>() as u64),
                },
                count: None,
            }],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("amstack render"),
            bind_group_layouts: &[Some(&camera_layout), Some(&object_layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("amstack render"),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &shader,
                entry_point: Some("vs_main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: size_of::<Vertex>() as u64,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3],
                })],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleList,
                front_face: wgpu::FrontFace::Ccw,
                cull_mode: Some(wgpu::Face::Back),
                ..wgpu::PrimitiveState::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                // Reversed depth: nearer is larger (camera.rs).
                depth_compare: Some(wgpu::CompareFunction::Greater),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &shader,
                entry_point: Some("fs_main"),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: COLOR_FORMAT,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });

        let align = u64::from(device.limits().min_uniform_buffer_offset_alignment).max(1);
        let slot_stride = (size_of::<ObjectUniform>() as u64).div_ceil(align) * align;

        let mut vehicle_shapes = Vec::new();
        let mut meshes = Vec::new();
        for (link, l) in vehicle.model.links.iter().enumerate() {
            // URDF material, else the vehicle file's [colors], else the default by role.
            #[allow(clippy::cast_possible_truncation)]
            let nominal = vehicle
                .link_colors
                .get(link)
                .copied()
                .flatten()
                .map_or_else(|| link_rgb(vehicle, link), |c| c.map(|v| v as f32));
            for g in &l.visuals {
                #[allow(clippy::cast_possible_truncation)]
                let rgb = g
                    .rgba
                    .map_or(nominal, |[r, gg, b, _]| [r as f32, gg as f32, b as f32]);
                vehicle_shapes.push(VehicleShape {
                    link,
                    link_from_shape: g.link_from_shape,
                    material: Material::plain(rgb),
                });
                meshes.push(Mesh::from_urdf_shape(&g.shape));
            }
        }
        let vehicle_meshes = GpuMeshes::new(&device, &queue, "vehicle", &meshes)?;
        let scene_meshes = GpuMeshes::new(&device, &queue, "scene", &[])?;

        let targets = cameras
            .iter()
            .map(|c| make_target(&device, &camera_layout, c))
            .collect::<Result<Vec<_>, _>>()?;
        let slots = make_slots(&device, &object_layout, slot_stride, vehicle_shapes.len());
        Ok(Self {
            device,
            queue,
            adapter,
            pipeline,
            object_layout,
            slot_stride,
            model: vehicle.model.clone(),
            dof: vehicle.model.dof(),
            vehicle_shapes,
            vehicle_meshes,
            scene_materials: Vec::new(),
            scene_meshes,
            lighting: Lighting::default(),
            dr,
            cameras: targets,
            slots,
            link_poses: Vec::with_capacity(vehicle.model.links.len()),
            in_flight: Vec::with_capacity(cameras.len()),
        })
    }

    /// The adapter in use (name, backend, device type), e.g. "llvmpipe (LLVM 15.0.6, 256 bits)".
    pub fn adapter(&self) -> &wgpu::AdapterInfo {
        &self.adapter
    }

    /// The cameras, by index.
    pub fn cameras(&self) -> impl ExactSizeIterator<Item = &CameraSpec> {
        self.cameras.iter().map(|c| &c.spec)
    }

    /// The index of the camera named `name`.
    pub fn camera_index(&self, name: &str) -> Option<usize> {
        self.cameras.iter().position(|c| c.spec.name == name)
    }

    /// Visual randomisation on or off.
    pub fn visual_dr(&self) -> VisualDr {
        self.dr
    }

    /// The light of the current episode.
    pub fn lighting(&self) -> &Lighting {
        &self.lighting
    }

    /// A new episode: the scene's shapes (from [`sim_twin::Twin::scene_visuals`]; tessellated
    /// here, once) and, with visual randomisation on, the look drawn from `seed`. With it off
    /// the look is nominal whatever the seed.
    pub fn reset_scene(&mut self, scene: &[SceneVisual], seed: u64) -> Result<(), RenderError> {
        let roles: Vec<_> = scene.iter().map(|s| s.role).collect();
        let appearance = Appearance::draw(self.dr, seed, &roles);
        let meshes = scene
            .iter()
            .enumerate()
            .map(|(index, s)| {
                Mesh::from_scene_shape(&s.shape).ok_or_else(|| RenderError::Shape {
                    index,
                    message: "a convex mesh has a triangle index out of range".to_owned(),
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        self.scene_meshes = GpuMeshes::new(&self.device, &self.queue, "scene", &meshes)?;
        self.scene_materials = appearance.materials;
        self.lighting = appearance.lighting;
        let needed = self.vehicle_shapes.len() + scene.len();
        if needed > self.slots.capacity {
            self.slots = make_slots(&self.device, &self.object_layout, self.slot_stride, needed);
        }
        Ok(())
    }

    /// The camera frame in the world at `state` (ROS optical: +z forward, +x right, +y down).
    pub fn world_from_camera(
        &mut self,
        state: &Snapshot,
        camera: usize,
    ) -> Result<Isometry3<f64>, RenderError> {
        self.check(state)?;
        self.model
            .forward_kinematics_into(&state.joint_positions, &mut self.link_poses);
        let target = self.target(camera)?;
        Ok(camera_pose(&target.spec, state, &self.link_poses))
    }

    fn target(&self, camera: usize) -> Result<&CameraTarget, RenderError> {
        self.cameras.get(camera).ok_or(RenderError::NoCamera {
            index: camera,
            count: self.cameras.len(),
        })
    }

    fn check(&self, state: &Snapshot) -> Result<(), RenderError> {
        if state.joint_positions.len() != self.dof {
            return Err(RenderError::State(format!(
                "{} joint positions for {} joints",
                state.joint_positions.len(),
                self.dof
            )));
        }
        if state.scene_poses.len() != self.scene_materials.len() {
            return Err(RenderError::State(format!(
                "{} scene poses for {} scene objects (reset the scene first)",
                state.scene_poses.len(),
                self.scene_materials.len()
            )));
        }
        let finite = |p: &Isometry3<f64>| {
            p.translation.vector.iter().all(|v| v.is_finite())
                && p.rotation.coords.iter().all(|v| v.is_finite())
        };
        if !finite(&state.world_from_base)
            || !state.joint_positions.iter().all(|q| q.is_finite())
            || !state.scene_poses.iter().all(finite)
        {
            return Err(RenderError::State(
                "a pose or joint is not finite".to_owned(),
            ));
        }
        Ok(())
    }

    /// One camera's image at `state`.
    pub fn render(&mut self, state: &Snapshot, camera: usize) -> Result<Image, RenderError> {
        let mut image = Image::default();
        self.render_set_into(state, &[camera], std::slice::from_mut(&mut image))?;
        Ok(image)
    }

    /// One camera's image at `state` into `image` (its buffer reused).
    pub fn render_into(
        &mut self,
        state: &Snapshot,
        camera: usize,
        image: &mut Image,
    ) -> Result<(), RenderError> {
        self.render_set_into(state, &[camera], std::slice::from_mut(image))
    }

    /// Several cameras of one state in one submission (e.g. EE + base of a tick):
    /// `images[k]` receives camera `cameras[k]`.
    pub fn render_set_into(
        &mut self,
        state: &Snapshot,
        cameras: &[usize],
        images: &mut [Image],
    ) -> Result<(), RenderError> {
        if images.len() != cameras.len() {
            return Err(RenderError::State(format!(
                "{} images for {} cameras",
                images.len(),
                cameras.len()
            )));
        }
        self.begin_frame(state, cameras)?;
        self.finish_frame(images)
    }

    /// Starts drawing `cameras` at `state` (one submission) and returns without waiting: the
    /// adapter renders while the caller goes on (e.g. steps the next tick's physics);
    /// [`Self::finish_frame`] waits and reads the images back. One frame at a time: beginning
    /// a second before finishing the first is an error.
    pub fn begin_frame(&mut self, state: &Snapshot, cameras: &[usize]) -> Result<(), RenderError> {
        if !self.in_flight.is_empty() {
            return Err(RenderError::State(
                "a frame is already in flight: finish it first".to_owned(),
            ));
        }
        self.check(state)?;
        for &c in cameras {
            self.target(c)?;
        }
        self.model
            .forward_kinematics_into(&state.joint_positions, &mut self.link_poses);
        self.write_objects(state);

        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("frame"),
            });
        for &c in cameras {
            let target = &self.cameras[c];
            let uniform = self.camera_uniform(&target.spec, state);
            self.queue
                .write_buffer(&target.uniform, 0, bytemuck::bytes_of(&uniform));
            self.encode_pass(&mut encoder, target);
        }
        self.queue.submit(Some(encoder.finish()));
        for &c in cameras {
            let target = &self.cameras[c];
            if let Ok(mut m) = target.mapped.lock() {
                *m = None;
            }
            let flag = Arc::clone(&target.mapped);
            target
                .readback
                .map_async(wgpu::MapMode::Read, .., move |r| {
                    if let Ok(mut m) = flag.lock() {
                        *m = Some(r);
                    }
                });
        }
        self.in_flight.extend_from_slice(cameras);
        Ok(())
    }

    /// Waits for the frame of [`Self::begin_frame`] and copies its images: `images[k]`
    /// receives the k-th camera begun. With the wrong number of images the frame stays in
    /// flight (call again with the right number).
    pub fn finish_frame(&mut self, images: &mut [Image]) -> Result<(), RenderError> {
        if images.len() != self.in_flight.len() {
            return Err(RenderError::State(format!(
                "{} images for a frame of {} cameras",
                images.len(),
                self.in_flight.len()
            )));
        }
        let waited = self
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| RenderError::Readback(e.to_string()));
        let mut result = waited;
        for (&c, image) in self.in_flight.iter().zip(images.iter_mut()) {
            let target = &self.cameras[c];
            let status = target.mapped.lock().ok().and_then(|mut m| m.take());
            let copied = match status {
                Some(Ok(())) => {
                    let copied = copy_out(target, image);
                    target.readback.unmap();
                    copied
                }
                Some(Err(e)) => Err(RenderError::Readback(e.to_string())),
                None => Err(RenderError::Readback("the map never completed".to_owned())),
            };
            result = result.and(copied);
        }
        self.in_flight.clear();
        result
    }

    fn camera_uniform(&self, spec: &CameraSpec, state: &Snapshot) -> CameraUniform {
        let world_from_camera = camera_pose(spec, state, &self.link_poses);
        let clip_from_world =
            spec.clip_from_camera() * world_from_camera.inverse().to_homogeneous();
        let l = &self.lighting;
        #[allow(clippy::cast_possible_truncation)]
        CameraUniform {
            clip_from_world: mat4_f32(&clip_from_world),
            toward_light: [
                l.toward_light.x as f32,
                l.toward_light.y as f32,
                l.toward_light.z as f32,
                0.0,
            ],
            light: [l.intensity, l.ambient, 0.0, 0.0],
        }
    }

    /// Every object's transform and material into the slots (one buffer write).
    fn write_objects(&mut self, state: &Snapshot) {
        let stride = usize::try_from(self.slot_stride).unwrap_or(usize::MAX);
        let n = self.vehicle_shapes.len() + self.scene_materials.len();
        let staging = &mut self.slots.staging;
        staging.clear();
        staging.resize(n * stride, 0);
        let mut put = |k: usize, pose: &Isometry3<f64>, m: &Material| {
            let u = ObjectUniform {
                world_from_object: mat4_f32(&pose.to_homogeneous()),
                material: m.gpu(),
            };
            let bytes = bytemuck::bytes_of(&u);
            staging[k * stride..k * stride + bytes.len()].copy_from_slice(bytes);
        };
        for (k, s) in self.vehicle_shapes.iter().enumerate() {
            let pose = state.world_from_base * self.link_poses[s.link] * s.link_from_shape;
            put(k, &pose, &s.material);
        }
        let offset = self.vehicle_shapes.len();
        for (k, (pose, m)) in state
            .scene_poses
            .iter()
            .zip(&self.scene_materials)
            .enumerate()
        {
            put(offset + k, pose, m);
        }
        if !staging.is_empty() {
            self.queue.write_buffer(&self.slots.buffer, 0, staging);
        }
    }

    fn encode_pass(&self, encoder: &mut wgpu::CommandEncoder, target: &CameraTarget) {
        let [r, g, b] = SKY_RGB.map(f64::from);
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some(&target.spec.name),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &target.color_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color { r, g, b, a: 1.0 }),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &target.depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &target.bind_group, &[]);
            let mut slot = 0u64;
            for (meshes, count) in [
                (&self.vehicle_meshes, self.vehicle_shapes.len()),
                (&self.scene_meshes, self.scene_materials.len()),
            ] {
                pass.set_vertex_buffer(0, meshes.vertices.slice(..));
                pass.set_index_buffer(meshes.indices.slice(..), wgpu::IndexFormat::Uint32);
                for range in meshes.ranges.iter().take(count) {
                    let offset = u32::try_from(slot * self.slot_stride).unwrap_or(u32::MAX);
                    pass.set_bind_group(1, &self.slots.bind_group, &[offset]);
                    pass.draw_indexed(
                        range.first_index..range.first_index + range.index_count,
                        range.base_vertex,
                        0..1,
                    );
                    slot += 1;
                }
            }
        }
        let k = &target.spec.intrinsics;
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &target.color,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &target.readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(target.padded_bytes_per_row),
                    rows_per_image: Some(k.height),
                },
            },
            wgpu::Extent3d {
                width: k.width,
                height: k.height,
                depth_or_array_layers: 1,
            },
        );
    }
}

/// World pose of a camera at `state` given the links' root_from_link poses.
fn camera_pose(
    spec: &CameraSpec,
    state: &Snapshot,
    link_poses: &[Isometry3<f64>],
) -> Isometry3<f64> {
    match spec.parent {
        CameraParent::World => spec.parent_from_camera,
        CameraParent::Link(l) => {
            let root_from_link = link_poses
                .get(l)
                .copied()
                .unwrap_or_else(Isometry3::identity);
            state.world_from_base * root_from_link * spec.parent_from_camera
        }
    }
}

/// RGBA rows (padded) of the mapped readback into RGB8.
fn copy_out(target: &CameraTarget, image: &mut Image) -> Result<(), RenderError> {
    let k = &target.spec.intrinsics;
    let view = target
        .readback
        .get_mapped_range(..)
        .map_err(|e| RenderError::Readback(e.to_string()))?;
    let (w, h) = (k.width as usize, k.height as usize);
    image.width = k.width;
    image.height = k.height;
    image.rgb.clear();
    image.rgb.reserve(3 * w * h);
    let stride = target.padded_bytes_per_row as usize;
    for row in 0..h {
        let Some(line) = view.get(row * stride..row * stride + 4 * w) else {
            return Err(RenderError::Readback(format!(
                "row {row} is out of the buffer"
            )));
        };
        for px in line.chunks_exact(4) {
            image.rgb.extend_from_slice(&px[..3]);
        }
    }
    Ok(())
}

fn make_target(
    device: &wgpu::Device,
    camera_layout: &wgpu::BindGroupLayout,
    spec: &CameraSpec,
) -> Result<CameraTarget, RenderError> {
    let k = &spec.intrinsics;
    let max = device.limits().max_texture_dimension_2d;
    if k.width > max || k.height > max {
        return Err(RenderError::Camera {
            name: spec.name.clone(),
            message: format!(
                "image {}×{} px exceeds the adapter's {max} px",
                k.width, k.height
            ),
        });
    }
    let size = wgpu::Extent3d {
        width: k.width,
        height: k.height,
        depth_or_array_layers: 1,
    };
    let texture = |label: &str, format, usage| {
        device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    };
    let color = texture(
        &spec.name,
        COLOR_FORMAT,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
    );
    let depth = texture(
        &spec.name,
        DEPTH_FORMAT,
        wgpu::TextureUsages::RENDER_ATTACHMENT,
    );
    let align = wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let padded_bytes_per_row = (4 * k.width).div_ceil(align) * align;
    let readback = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(&spec.name),
        size: u64::from(padded_bytes_per_row) * u64::from(k.height),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let uniform = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(&spec.name),
        size: size_of::<CameraUniform>() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(&spec.name),
        layout: camera_layout,
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: uniform.as_entire_binding(),
        }],
    });
    Ok(CameraTarget {
        spec: spec.clone(),
        color_view: color.create_view(&wgpu::TextureViewDescriptor::default()),
        depth_view: depth.create_view(&wgpu::TextureViewDescriptor::default()),
        color,
        readback,
        padded_bytes_per_row,
        uniform,
        bind_group,
        mapped: Arc::new(Mutex::new(None)),
    })
}

fn make_slots(
    device: &wgpu::Device,
    object_layout: &wgpu::BindGroupLayout,
    stride: u64,
    count: usize,
) -> ObjectSlots {
    let capacity = count.max(1);
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("objects"),
        size: stride * capacity as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("objects"),
        layout: object_layout,
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &buffer,
                offset: 0,
                size: wgpu::BufferSize::new(size_of::<ObjectUniform>() as u64),
            }),
        }],
    });
    ObjectSlots {
        buffer,
        bind_group,
        capacity,
        staging: Vec::with_capacity(stride as usize * capacity),
    }
}

/// The first adapter wgpu offers and a device with its default limits. Backends: those of
/// `WGPU_BACKEND` when it is set; otherwise Vulkan, Metal or DX12 first, OpenGL only when none
/// of those has an adapter (probing OpenGL's EGL displays prints warnings on a headless
/// machine).
async fn open_device() -> Result<(wgpu::Device, wgpu::Queue, wgpu::AdapterInfo), RenderError> {
    let from_env = std::env::var_os("WGPU_BACKEND").is_some();
    let attempts: &[Option<wgpu::Backends>] = if from_env {
        &[None]
    } else {
        &[Some(wgpu::Backends::PRIMARY), Some(wgpu::Backends::GL)]
    };
    let mut failure = String::from("no backend tried");
    for backends in attempts {
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        if let Some(b) = backends {
            descriptor.backends = *b;
        }
        let instance = wgpu::Instance::new(descriptor);
        let adapter = match instance
            .request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: false,
                compatible_surface: None,
                ..Default::default()
            })
            .await
        {
            Ok(a) => a,
            Err(e) => {
                failure = e.to_string();
                continue;
            }
        };
        let info = adapter.get_info();
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("amstack render"),
                required_features: wgpu::Features::empty(),
                required_limits: wgpu::Limits::downlevel_defaults()
                    .using_resolution(adapter.limits()),
                ..Default::default()
            })
            .await
            .map_err(|e| RenderError::Device {
                adapter: info.name.clone(),
                message: e.to_string(),
            })?;
        return Ok((device, queue, info));
    }
    Err(RenderError::NoAdapter(failure))
}
