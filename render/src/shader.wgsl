// The renderer's one shader: rigid objects, Lambert shading with a directional light and
// ambient, procedural textures in the object's frame (appearance.rs documents them).

struct Camera {
    clip_from_world: mat4x4<f32>,
    // xyz: unit vector toward the light (world); w unused.
    toward_light: vec4<f32>,
    // x: directional intensity, y: ambient.
    light: vec4<f32>,
};

struct Object {
    world_from_object: mat4x4<f32>,
    rgb: vec4<f32>,
    rgb2: vec4<f32>,
    // x: pattern (0 plain, 1 checker, 2 stripes, 3 noise), y: period in m.
    pattern: vec4<f32>,
    // xyz: stripe direction (object frame).
    axis: vec4<f32>,
};

@group(0) @binding(0) var<uniform> camera: Camera;
@group(1) @binding(0) var<uniform> object: Object;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal_in_world: vec3<f32>,
    @location(1) position_in_object: vec3<f32>,
};

@vertex
fn vs_main(@location(0) position: vec3<f32>, @location(1) normal: vec3<f32>) -> VertexOut {
    var out: VertexOut;
    let world = object.world_from_object * vec4<f32>(position, 1.0);
    out.clip = camera.clip_from_world * world;
    out.normal_in_world = (object.world_from_object * vec4<f32>(normal, 0.0)).xyz;
    out.position_in_object = position;
    return out;
}

// An integer hash of a cell (PCG-like), to [0, 1).
fn hash_cell(c: vec3<i32>) -> f32 {
    var h = bitcast<u32>(c.x) * 73856093u ^ bitcast<u32>(c.y) * 19349663u ^ bitcast<u32>(c.z) * 83492791u;
    h = h * 747796405u + 2891336453u;
    h = ((h >> ((h >> 28u) + 4u)) ^ h) * 277803737u;
    h = (h >> 22u) ^ h;
    return f32(h & 0xffffu) / 65536.0;
}

fn albedo(p: vec3<f32>) -> vec3<f32> {
    let kind = i32(object.pattern.x + 0.5);
    let period = max(object.pattern.y, 1e-4);
    if (kind == 1) {
        let c = vec3<i32>(floor(p / period));
        let parity = (c.x + c.y + c.z) & 1;
        return select(object.rgb.rgb, object.rgb2.rgb, parity == 1);
    }
    if (kind == 2) {
        let s = i32(floor(dot(p, object.axis.xyz) / period)) & 1;
        return select(object.rgb.rgb, object.rgb2.rgb, s == 1);
    }
    if (kind == 3) {
        let t = hash_cell(vec3<i32>(floor(p / period)));
        return mix(object.rgb.rgb, object.rgb2.rgb, t);
    }
    return object.rgb.rgb;
}

@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    let n = normalize(in.normal_in_world);
    let diffuse = max(dot(n, camera.toward_light.xyz), 0.0);
    let shade = camera.light.y + camera.light.x * diffuse;
    let rgb = clamp(albedo(in.position_in_object) * shade, vec3<f32>(0.0), vec3<f32>(1.0));
    return vec4<f32>(rgb, 1.0);
}
