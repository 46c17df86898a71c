//! Embree through its C API, one ray at a time (`rtcIntersect1` / `rtcOccluded1`): the
//! honest same-process baseline of `edgepoint-bench rays`. The library is opened at run time
//! from the path given with `--embree` (`dlopen`), so the bench needs no Embree to build and
//! can hold two versions at once: Embree 3 (Debian's `libembree3-3`) and Embree 4 (the
//! shared library inside PyPI's `embreex` wheel, whose version 4.4.0 is the one issue 14
//! item 5 measured). The two APIs differ only in the trace calls' arguments: Embree 3 takes
//! an intersect context before the ray, Embree 4 optional arguments after it (null: the
//! defaults). Each library is opened `RTLD_LOCAL`, so the two sets of `rtc*` symbols do not
//! meet.
use super::Tracer;
use anyhow::{bail, Context, Result};
use glam::Vec3;
use std::ffi::{c_char, c_void, CStr, CString};
use std::path::Path;
use std::sync::Arc;

type Handle = *mut c_void;

/// `struct RTCIntersectContext` of Embree 3.13 with `RTC_MAX_INSTANCE_LEVEL_COUNT` 1 and
/// `RTC_MIN_WIDTH` 0 (what Debian's build sets in `rtcore_config.h`).
#[repr(C)]
struct IntersectContext3 {
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

/// `struct RTCHit` with one instance level. Embree 4 built with instance arrays adds
/// `instPrimID` after `instID`; the field is here for it (Embree 3 and an Embree 4 without
/// them never touch it: the ray is read and the hit written by offset).
#[repr(C, align(16))]
#[derive(Clone, Copy)]
struct RtcHit {
    ng: [f32; 3],
    u: f32,
    v: f32,
    prim_id: u32,
    geom_id: u32,
    inst_id: [u32; 1],
    inst_prim_id: [u32; 1],
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
const DEVICE_PROPERTY_VERSION: u32 = 0;
const INTERSECT_CONTEXT_FLAG_INCOHERENT: u32 = 0;

/// The trace calls, whose signatures differ between the major versions.
#[derive(Clone, Copy)]
enum Trace {
    V3 {
        intersect: unsafe extern "C" fn(Handle, *mut IntersectContext3, *mut RtcRayHit),
        occluded: unsafe extern "C" fn(Handle, *mut IntersectContext3, *mut RtcRay),
    },
    V4 {
        intersect: unsafe extern "C" fn(Handle, *mut RtcRayHit, *const c_void),
        occluded: unsafe extern "C" fn(Handle, *mut RtcRay, *const c_void),
    },
}

/// An opened Embree library: its entry points and version. It is never closed: Embree's
/// task scheduler keeps threads of its own that must not outlive its code.
pub struct Library {
    /// "embree3" or "embree4": the tracer's name in the bench's output.
    pub name: &'static str,
    /// The library's own version, e.g. "4.4.0" (`rtcGetDeviceProperty`).
    pub version: String,
    new_device: unsafe extern "C" fn(*const c_char) -> Handle,
    release_device: unsafe extern "C" fn(Handle),
    device_error: unsafe extern "C" fn(Handle) -> u32,
    new_scene: unsafe extern "C" fn(Handle) -> Handle,
    release_scene: unsafe extern "C" fn(Handle),
    commit_scene: unsafe extern "C" fn(Handle),
    new_geometry: unsafe extern "C" fn(Handle, u32) -> Handle,
    new_buffer: unsafe extern "C" fn(Handle, u32, u32, u32, usize, usize) -> *mut c_void,
    commit_geometry: unsafe extern "C" fn(Handle),
    attach_geometry: unsafe extern "C" fn(Handle, Handle) -> u32,
    release_geometry: unsafe extern "C" fn(Handle),
    trace: Trace,
}

// SAFETY: entry points of a library that stays loaded; Embree's API is thread-safe for what the
// bench does (builds on one thread at a time, traces of a committed scene from many).
unsafe impl Send for Library {}
unsafe impl Sync for Library {}

fn dl_error() -> String {
    // SAFETY: dlerror returns null or a NUL-terminated string valid until the next dl call.
    unsafe {
        let e = libc::dlerror();
        if e.is_null() {
            "unknown error".into()
        } else {
            CStr::from_ptr(e).to_string_lossy().into_owned()
        }
    }
}

impl Library {
    /// Opens the shared library at `path` and checks it is Embree 3 or 4.
    pub fn open(path: &Path) -> Result<Arc<Library>> {
        let c = CString::new(path.as_os_str().as_encoded_bytes()).context("a path with a NUL byte")?;
        // SAFETY: dlopen of a path; Embree's initialisers run, nothing else of ours.
        let lib = unsafe { libc::dlopen(c.as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL) };
        if lib.is_null() {
            bail!("{}: cannot open as a shared library: {}", path.display(), dl_error());
        }
        macro_rules! sym {
            ($name:literal) => {{
                // SAFETY: the symbol is Embree's function of that name, whose C signature the
                // field's type restates (checked against rtcore_device.h / rtcore_scene.h /
                // rtcore_geometry.h of 3.13 and 4.4).
                let p = unsafe { libc::dlsym(lib, concat!($name, "\0").as_ptr() as *const c_char) };
                if p.is_null() {
                    bail!("{}: no symbol {} (is it Embree?): {}", path.display(), $name, dl_error());
                }
                unsafe { std::mem::transmute::<*mut c_void, _>(p) }
            }};
        }
        let device_property: unsafe extern "C" fn(Handle, u32) -> isize = sym!("rtcGetDeviceProperty");
        let new_device: unsafe extern "C" fn(*const c_char) -> Handle = sym!("rtcNewDevice");
        let release_device: unsafe extern "C" fn(Handle) = sym!("rtcReleaseDevice");
        // The version from a throw-away device (RTC_DEVICE_PROPERTY_VERSION: 40400 for 4.4.0).
        let version = unsafe {
            let d = new_device(std::ptr::null());
            if d.is_null() {
                bail!("{}: rtcNewDevice failed", path.display());
            }
            let v = device_property(d, DEVICE_PROPERTY_VERSION);
            release_device(d);
            v
        };
        let (major, minor, patch) = (version / 10000, version / 100 % 100, version % 100);
        let (name, trace) = match major {
            3 => ("embree3", Trace::V3 { intersect: sym!("rtcIntersect1"), occluded: sym!("rtcOccluded1") }),
            4 => ("embree4", Trace::V4 { intersect: sym!("rtcIntersect1"), occluded: sym!("rtcOccluded1") }),
            _ => bail!("{}: Embree {major}.{minor}.{patch}; the bench speaks the APIs of Embree 3 and 4", path.display()),
        };
        Ok(Arc::new(Library {
            name,
            version: format!("{major}.{minor}.{patch}"),
            new_device,
            release_device,
            device_error: sym!("rtcGetDeviceError"),
            new_scene: sym!("rtcNewScene"),
            release_scene: sym!("rtcReleaseScene"),
            commit_scene: sym!("rtcCommitScene"),
            new_geometry: sym!("rtcNewGeometry"),
            new_buffer: sym!("rtcSetNewGeometryBuffer"),
            commit_geometry: sym!("rtcCommitGeometry"),
            attach_geometry: sym!("rtcAttachGeometry"),
            release_geometry: sym!("rtcReleaseGeometry"),
            trace,
        }))
    }
}

/// One triangle mesh in an Embree scene (default build quality, as `rtcCommitScene` does
/// unless told otherwise).
pub struct EmbreeMesh {
    lib: Arc<Library>,
    device: Handle,
    scene: Handle,
}

// SAFETY: Embree documents a committed scene as safe to trace from any number of threads.
unsafe impl Sync for EmbreeMesh {}
unsafe impl Send for EmbreeMesh {}

impl EmbreeMesh {
    /// Builds the scene on a device limited to `threads` build threads.
    pub fn build(lib: &Arc<Library>, positions: &[Vec3], triangles: &[[u32; 3]], threads: usize) -> Result<EmbreeMesh> {
        let config = CString::new(format!("threads={threads}")).expect("no NUL");
        let l = lib.as_ref();
        // SAFETY: the Embree C API used as documented; buffers are written within the sizes
        // Embree allocated for them, and every handle is checked before use.
        unsafe {
            let device = (l.new_device)(config.as_ptr());
            anyhow::ensure!(!device.is_null(), "rtcNewDevice failed");
            let scene = (l.new_scene)(device);
            let geom = (l.new_geometry)(device, GEOMETRY_TYPE_TRIANGLE);
            let v = (l.new_buffer)(geom, BUFFER_TYPE_VERTEX, 0, FORMAT_FLOAT3, 12, positions.len()) as *mut f32;
            let i = (l.new_buffer)(geom, BUFFER_TYPE_INDEX, 0, FORMAT_UINT3, 12, triangles.len()) as *mut u32;
            anyhow::ensure!(!v.is_null() && !i.is_null(), "Embree buffer allocation failed (error {})", (l.device_error)(device));
            for (k, p) in positions.iter().enumerate() {
                std::ptr::copy_nonoverlapping(p.to_array().as_ptr(), v.add(3 * k), 3);
            }
            std::ptr::copy_nonoverlapping(triangles.as_ptr() as *const u32, i, 3 * triangles.len());
            (l.commit_geometry)(geom);
            (l.attach_geometry)(scene, geom);
            (l.release_geometry)(geom);
            (l.commit_scene)(scene);
            let err = (l.device_error)(device);
            anyhow::ensure!(err == 0, "Embree scene build failed (error {err})");
            Ok(EmbreeMesh { lib: lib.clone(), device, scene })
        }
    }

    /// Embree 3's context: the default flags (incoherent: a hint for ray streams, which one
    /// ray at a time is not); Embree 4 is given null arguments, its defaults.
    fn context3(&self) -> IntersectContext3 {
        IntersectContext3 { flags: INTERSECT_CONTEXT_FLAG_INCOHERENT, filter: std::ptr::null(), inst_id: [INVALID_ID] }
    }
}

fn ray(o: Vec3, d: Vec3, tmax: f32) -> RtcRay {
    RtcRay { org: o.to_array(), tnear: 0.0, dir: d.to_array(), time: 0.0, tfar: tmax, mask: u32::MAX, id: 0, flags: 0 }
}

impl Tracer for EmbreeMesh {
    fn closest(&self, o: Vec3, d: Vec3, tmax: f32) -> Option<(f32, u32)> {
        let hit = RtcHit { ng: [0.0; 3], u: 0.0, v: 0.0, prim_id: INVALID_ID, geom_id: INVALID_ID, inst_id: [INVALID_ID], inst_prim_id: [INVALID_ID] };
        let mut rh = RtcRayHit { ray: ray(o, d, tmax), hit };
        // SAFETY: a committed scene and properly aligned, initialised structures.
        unsafe {
            match self.lib.trace {
                Trace::V3 { intersect, .. } => intersect(self.scene, &mut self.context3(), &mut rh),
                Trace::V4 { intersect, .. } => intersect(self.scene, &mut rh, std::ptr::null()),
            }
        }
        (rh.hit.geom_id != INVALID_ID).then_some((rh.ray.tfar, rh.hit.prim_id))
    }

    fn occluded(&self, o: Vec3, d: Vec3, tmax: f32) -> bool {
        let mut r = ray(o, d, tmax);
        // SAFETY: as above; Embree sets tfar to -inf when the ray is occluded.
        unsafe {
            match self.lib.trace {
                Trace::V3 { occluded, .. } => occluded(self.scene, &mut self.context3(), &mut r),
                Trace::V4 { occluded, .. } => occluded(self.scene, &mut r, std::ptr::null()),
            }
        }
        r.tfar < 0.0
    }
}

impl Drop for EmbreeMesh {
    fn drop(&mut self) {
        // SAFETY: handles created in `build`, released once.
        unsafe {
            (self.lib.release_scene)(self.scene);
            (self.lib.release_device)(self.device);
        }
    }
}
