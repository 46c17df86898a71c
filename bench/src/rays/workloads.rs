//! The three ray workloads of issue 14 item 5, built from the mesh's bounding box.
use edgepoint_scene::Camera;
use glam::Vec3;

#[derive(Clone, Copy, Debug)]
pub struct BenchRay {
    pub o: Vec3,
    pub d: Vec3,
    pub tmax: f32,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum WorkloadKind {
    Closest,
    Occlusion,
}

pub struct Workload {
    pub name: &'static str,
    pub kind: WorkloadKind,
    pub rays: Vec<BenchRay>,
}

/// A pinhole camera at the box centre + (0, 0, 0.25) looking at the centre, up +Y, 40°
/// vertical field of view: one ray through every pixel centre of a `side`² image.
pub fn primary(lo: Vec3, hi: Vec3, side: u32) -> Workload {
    let c = (lo + hi) * 0.5;
    let cam = Camera { eye: c + Vec3::new(0.0, 0.0, 0.25), target: c, up: Vec3::Y, fov_y_degrees: 40.0 }.frame(side, side);
    let rays = (0..side * side)
        .map(|i| {
            let (o, d) = cam.ray((i % side) as f32 + 0.5, (i / side) as f32 + 0.5);
            BenchRay { o, d, tmax: f32::INFINITY }
        })
        .collect();
    Workload { name: "primary", kind: WorkloadKind::Closest, rays }
}

/// Shadow rays from the primary rays' hits (`hit` gives t and the unit geometric normal)
/// to a point light at the box centre + (0.2, 0.3, 0.2), starting 1e-5 off the surface
/// along the normal on the side the primary ray came from; unit directions, `tmax` the
/// distance to the light.
pub fn shadow(lo: Vec3, hi: Vec3, primary: &Workload, hit: impl Fn(Vec3, Vec3, f32) -> Option<(f32, Vec3)> + Sync) -> Workload {
    use rayon::prelude::*;
    let light = (lo + hi) * 0.5 + Vec3::new(0.2, 0.3, 0.2);
    let rays = primary
        .rays
        .par_iter()
        .filter_map(|r| {
            let (t, n) = hit(r.o, r.d, r.tmax)?;
            let n = if n.dot(r.d) < 0.0 { n } else { -n };
            let o = r.o + r.d * t + n * 1e-5;
            let to = light - o;
            let dist = to.length();
            Some(BenchRay { o, d: to / dist, tmax: dist })
        })
        .collect();
    Workload { name: "shadow", kind: WorkloadKind::Occlusion, rays }
}

/// `n` rays with origins uniform in the box and directions uniform on the sphere
/// (closest hit), from a fixed seed.
pub fn incoherent(lo: Vec3, hi: Vec3, n: usize, seed: u64) -> Workload {
    let mut s = seed;
    // SplitMix64: independent uniform floats in [0, 1).
    let mut u = move || {
        s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = s;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    };
    let rays = (0..n)
        .map(|_| {
            let o = lo + (hi - lo) * Vec3::new(u(), u(), u());
            let z = 1.0 - 2.0 * u();
            let phi = std::f32::consts::TAU * u();
            let r = (1.0 - z * z).max(0.0).sqrt();
            BenchRay { o, d: Vec3::new(r * phi.cos(), r * phi.sin(), z), tmax: f32::INFINITY }
        })
        .collect();
    Workload { name: "incoherent", kind: WorkloadKind::Closest, rays }
}
