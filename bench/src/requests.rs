//! Request generation shared by the worker benchmarks (`throughput`, `loadtest`): random
//! primary rays over the image, as the renderer's sparse sampling requests them, and their
//! wire batches.
use edgepoint_proto as pb;
use edgepoint_worker::RayRequest;
use std::collections::HashMap;

pub use edgepoint_proto::shaders::parse_param;

/// Random primary rays through a 512x512 image of the scene camera: the same mix the
/// renderer requests (sparse pixels all over the image).
pub struct RayGen {
    cam: edgepoint_scene::camera::CameraFrame,
    state: u64,
    next_id: u64,
}

impl RayGen {
    pub fn new(camera: &edgepoint_scene::Camera, seed: u64) -> Self {
        RayGen { cam: camera.frame(512, 512), state: seed | 1, next_id: 0 }
    }
    fn uniform(&mut self) -> f32 {
        // xorshift64*: enough for spreading rays over the image.
        self.state ^= self.state >> 12;
        self.state ^= self.state << 25;
        self.state ^= self.state >> 27;
        (self.state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32 / (1u64 << 24) as f32
    }
    pub fn batch(&mut self, n: usize) -> Vec<RayRequest> {
        (0..n)
            .map(|_| {
                let (sx, sy) = (self.uniform() * 512.0, self.uniform() * 512.0);
                let (origin, direction) = self.cam.ray(sx, sy);
                self.next_id += 1;
                RayRequest { id: self.next_id, pixel: [sx as u32, sy as u32], origin, direction }
            })
            .collect()
    }
}

pub fn to_wire(id: u64, epoch: u64, shader: &str, params: &HashMap<String, f64>, reqs: Vec<RayRequest>) -> pb::RequestBatch {
    pb::RequestBatch {
        batch_id: id,
        epoch,
        shader: shader.to_string(),
        params: params.clone(),
        seed: id,
        // Unpacked: the benches that talk to a worker directly read its answers' `samples`.
        packed_requests: Vec::new(),
        requests: reqs
            .into_iter()
            .map(|r| pb::ShadeRequest {
                id: r.id,
                pixel_x: r.pixel[0],
                pixel_y: r.pixel[1],
                origin: Some(r.origin.into()),
                direction: Some(r.direction.into()),
                ..Default::default()
            })
            .collect(),
    }
}
