//! Embree 3 (Debian's `libembree-dev`) through its C API, one ray at a time
//! (`rtcIntersect1` / `rtcOccluded1`): the honest same-process baseline of
//! `edgepoint-bench rays`. Only built with the bench's `embree` feature, since the library
//! is a system package the project does not otherwise need.
use super::Tracer;
use glam::Vec3;
use std::ffi::{c_char, c_void, CString};

#[repr(C)]
struct RtcDevice(c_void);
#[repr(C)]
struct RtcScene(c_void);
#[repr(C)]
struct RtcGeometry(c_void);

/// `struct RTCIntersectContext` of Embree 3.13 with `RTC_MAX_INSTANCE_LEVEL_COUNT` 1 and
/// `RTC_MIN_WIDTH` 0 (what Debian's build sets in `rtcore_config.h`).
#[repr(C)]
struct IntersectContext {
    flags: u32,
    filter: *const c_void,
    inst_id: [u32; 1],
}

#[repr(C, align(16))]
#[derive(Clone, Copy)]
struct RtcRay {
    org: [f32; 3],
    tnear: f32,
    dir: [f32; 3],
    time: f32,
    tfar: f32,
    mask: u32,
    id: u32,
    flags: u32,
}

#[repr(C, align(16))]
#[derive(Clone, Copy)]
struct RtcHit {
    ng: [f32; 3],
    u: f32,
    v: f32,
    prim_id: u32,
    geom_id: u32,
    inst_id: [u32; 1],
}

#[repr(C)]
struct RtcRayHit {
    ray: RtcRay,
    hit: RtcHit,
}

const INVALID_ID: u32 = u32::MAX;
const GEOMETRY_TYPE_TRIANGLE: u32 = 0;
const BUFFER_TYPE_INDEX: u32 = 0;
const BUFFER_TYPE_VERTEX: u32 = 1;
const FORMAT_UINT3: u32 = 0x5003;
const FORMAT_FLOAT3: u32 = 0x9003;
const INTERSECT_CONTEXT_FLAG_INCOHERENT: u32 = 0;
const INTERSECT_CONTEXT_FLAG_COHERENT: u32 = 1;

#[link(name = "embree3")]
extern "C" {
    fn rtcNewDevice(config: *const c_char) -> *mut RtcDevice;
    fn rtcReleaseDevice(device: *mut RtcDevice);
    fn rtcGetDeviceError(device: *mut RtcDevice) -> u32;
    fn rtcNewScene(device: *mut RtcDevice) -> *mut RtcScene;
    fn rtcReleaseScene(scene: *mut RtcScene);
    fn rtcCommitScene(scene: *mut RtcScene);
    fn rtcNewGeometry(device: *mut RtcDevice, kind: u32) -> *mut RtcGeometry;
    fn rtcSetNewGeometryBuffer(geometry: *mut RtcGeometry, kind: u32, slot: u32, format: u32, byte_stride: usize, count: usize) -> *mut c_void;
    fn rtcCommitGeometry(geometry: *mut RtcGeometry);
    fn rtcAttachGeometry(scene: *mut RtcScene, geometry: *mut RtcGeometry) -> u32;
    fn rtcReleaseGeometry(geometry: *mut RtcGeometry);
    fn rtcIntersect1(scene: *mut RtcScene, context: *mut IntersectContext, rayhit: *mut RtcRayHit);
    fn rtcOccluded1(scene: *mut RtcScene, context: *mut IntersectContext, ray: *mut RtcRay);
}

/// One triangle mesh in an Embree scene (default build quality, as `rtcCommitScene` does
/// unless told otherwise).
pub struct EmbreeMesh {
    device: *mut RtcDevice,
    scene: *mut RtcScene,
    /// Whether the rays of the current workload are coherent (a hint Embree takes per call).
    pub coherent: bool,
}

// SAFETY: Embree documents a committed scene as safe to trace from any number of threads.
unsafe impl Sync for EmbreeMesh {}
unsafe impl Send for EmbreeMesh {}

impl EmbreeMesh {
    /// Builds the scene on a device limited to `threads` build threads.
    pub fn build(positions: &[Vec3], triangles: &[[u32; 3]], threads: usize) -> anyhow::Result<EmbreeMesh> {
        let config = CString::new(format!("threads={threads}")).expect("no NUL");
        // SAFETY: the Embree C API used as documented; buffers are written within the sizes
        // Embree allocated for them, and every handle is checked before use.
        unsafe {
            let device = rtcNewDevice(config.as_ptr());
            anyhow::ensure!(!device.is_null(), "rtcNewDevice failed");
            let scene = rtcNewScene(device);
            let geom = rtcNewGeometry(device, GEOMETRY_TYPE_TRIANGLE);
            let v = rtcSetNewGeometryBuffer(geom, BUFFER_TYPE_VERTEX, 0, FORMAT_FLOAT3, 12, positions.len()) as *mut f32;
            let i = rtcSetNewGeometryBuffer(geom, BUFFER_TYPE_INDEX, 0, FORMAT_UINT3, 12, triangles.len()) as *mut u32;
            anyhow::ensure!(!v.is_null() && !i.is_null(), "Embree buffer allocation failed (error {})", rtcGetDeviceError(device));
            for (k, p) in positions.iter().enumerate() {
                std::ptr::copy_nonoverlapping(p.to_array().as_ptr(), v.add(3 * k), 3);
            }
            std::ptr::copy_nonoverlapping(triangles.as_ptr() as *const u32, i, 3 * triangles.len());
            rtcCommitGeometry(geom);
            rtcAttachGeometry(scene, geom);
            rtcReleaseGeometry(geom);
            rtcCommitScene(scene);
            let err = rtcGetDeviceError(device);
            anyhow::ensure!(err == 0, "Embree scene build failed (error {err})");
            Ok(EmbreeMesh { device, scene, coherent: false })
        }
    }

    fn context(&self) -> IntersectContext {
        let flags = if self.coherent { INTERSECT_CONTEXT_FLAG_COHERENT } else { INTERSECT_CONTEXT_FLAG_INCOHERENT };
        IntersectContext { flags, filter: std::ptr::null(), inst_id: [INVALID_ID] }
    }
}

fn ray(o: Vec3, d: Vec3, tmax: f32) -> RtcRay {
    RtcRay { org: o.to_array(), tnear: 0.0, dir: d.to_array(), time: 0.0, tfar: tmax, mask: u32::MAX, id: 0, flags: 0 }
}

impl Tracer for EmbreeMesh {
    fn closest(&self, o: Vec3, d: Vec3, tmax: f32) -> Option<(f32, u32)> {
        let mut ctx = self.context();
        let hit = RtcHit { ng: [0.0; 3], u: 0.0, v: 0.0, prim_id: INVALID_ID, geom_id: INVALID_ID, inst_id: [INVALID_ID] };
        let mut rh = RtcRayHit { ray: ray(o, d, tmax), hit };
        // SAFETY: a committed scene and properly aligned, initialised structures.
        unsafe { rtcIntersect1(self.scene, &mut ctx, &mut rh) };
        (rh.hit.geom_id != INVALID_ID).then_some((rh.ray.tfar, rh.hit.prim_id))
    }

    fn occluded(&self, o: Vec3, d: Vec3, tmax: f32) -> bool {
        let mut ctx = self.context();
        let mut r = ray(o, d, tmax);
        // SAFETY: as above; Embree sets tfar to -inf when the ray is occluded.
        unsafe { rtcOccluded1(self.scene, &mut ctx, &mut r) };
        r.tfar < 0.0
    }
}

impl Drop for EmbreeMesh {
    fn drop(&mut self) {
        // SAFETY: handles created in `build`, released once.
        unsafe {
            rtcReleaseScene(self.scene);
            rtcReleaseDevice(self.device);
        }
    }
}
