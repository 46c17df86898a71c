//! What a session costs in memory, and the server-wide budget sessions draw from
//! (`--max-memory-mib`). The estimate adds up the session's image-sized structures, each
//! by its own `bytes_for` next to its constructor, so a buffer added to one of them is
//! counted by changing that function alone (and the tests that compare each `bytes_for`
//! with what a counting allocator sees catch one that was not). Counted are allocations,
//! not resident pages: reserved capacity (the Render Cache's replacement queues) counts
//! from the start, since it fills as the session runs.
use super::settings::SessionSettings;
use super::frame_loop::{OUTSTANDING_FRAMES, REST_FRAMES};
use super::requests::RequestRing;
use crate::epi::spread::BaselineHoles;
use crate::epi::Epi;
use crate::render_cache::holes::{HoleFill, ObjectFill};
use crate::render_cache::RenderCache;
use crate::sampling::Sampler;
use crate::visibility::Visibility;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// Encoded frames a session may hold at once: the newest in its output slot, one in the
/// stream's channel, one being written to the socket.
pub const FRAMES_IN_FLIGHT: usize = 3;
/// Bytes per pixel of one encoded frame at worst (QOI's worst case is 4 bytes per RGB
/// pixel, and its buffer may have grown past that by doubling), plus the 3-byte sRGB
/// image it is encoded from.
pub const FRAME_BYTES_PER_PIXEL: usize = 6;

/// A session's memory by part, in bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionMemory {
    pub parts: Vec<(&'static str, u64)>,
}

impl SessionMemory {
    /// The estimate for a `width` × `height` session with `points_per_pixel` and
    /// `settings`, its per-pixel passes running on `threads` threads.
    pub fn estimate(width: u32, height: u32, points_per_pixel: f32, settings: &SessionSettings, threads: usize) -> SessionMemory {
        let pixels = width as usize * height as usize;
        let parts = vec![
            ("render cache", RenderCache::bytes_for(width, height, points_per_pixel, threads)),
            ("edge-and-point image", Epi::bytes_for(width, height)),
            ("hole-fill pyramid", HoleFill::bytes_for(width, height)),
            ("object hole fill", ObjectFill::bytes_for(width, height)),
            ("exact visibility", Visibility::bytes_for(width, height)),
            ("baseline hole fill", BaselineHoles::bytes_for(width as usize, height as usize)),
            ("sampling priorities", Sampler::bytes_for(width, height)),
            ("sampling picks", Sampler::picks_bytes_for(width, height)),
            ("request ring", RequestRing::bytes_for(ring_capacity(settings, pixels))),
            ("requests in flight", requests_in_flight(settings, pixels) * REQUEST_IN_FLIGHT_BYTES),
            ("frames in flight", (FRAMES_IN_FLIGHT * 4 + FRAME_BYTES_PER_PIXEL) * pixels),
        ];
        SessionMemory { parts: parts.into_iter().map(|(k, v)| (k, v as u64)).collect() }
    }

    pub fn total(&self) -> u64 {
        self.parts.iter().map(|p| p.1).sum()
    }
}

/// Requests a session may have picked and not yet had answered at once, held in the session
/// or out at the workers: [`super::frame_loop::max_outstanding`]'s largest value, at rest
/// (frames of budget, [`REST_FRAMES`] of them). A fast pool keeps it there at rest.
pub fn requests_in_flight(s: &SessionSettings, pixels: usize) -> usize {
    s.frame_budget(pixels) * OUTSTANDING_FRAMES * REST_FRAMES
}

/// Bytes a request in flight costs at most: its record in the held batch, its packed copy on
/// the way to the worker, and its answer packed and unpacked (at 512² and the default
/// sparseness, 131,072 requests: 40 MB).
pub const REQUEST_IN_FLIGHT_BYTES: usize = std::mem::size_of::<edgepoint_proto::ShadeRequest>()
    + edgepoint_proto::packed::REQUEST_BYTES
    + std::mem::size_of::<edgepoint_proto::Sample>()
    + edgepoint_proto::packed::SAMPLE_BYTES;

/// Ring size: all requests that can be outstanding or held ([`requests_in_flight`]), twice
/// over, so an answer arriving late still finds its request.
pub fn ring_capacity(s: &SessionSettings, pixels: usize) -> usize {
    2 * requests_in_flight(s, pixels)
}

fn mib(bytes: u64) -> String {
    format!("{:.0} MiB", bytes as f64 / (1u64 << 20) as f64)
}

/// The server-wide memory budget sessions draw from.
#[derive(Debug)]
pub struct MemoryBudget {
    limit: u64,
    used: AtomicU64,
}

impl MemoryBudget {
    pub fn new(limit_bytes: u64) -> Arc<MemoryBudget> {
        Arc::new(MemoryBudget { limit: limit_bytes, used: AtomicU64::new(0) })
    }

    /// A budget that grants everything (library users and tests that do not limit).
    pub fn unlimited() -> Arc<MemoryBudget> {
        Self::new(u64::MAX)
    }

    pub fn limit(&self) -> u64 {
        self.limit
    }

    /// Bytes granted now.
    pub fn used(&self) -> u64 {
        self.used.load(Ordering::SeqCst)
    }

    fn take(&self, bytes: u64) -> Result<(), u64> {
        self.used.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |u| u.checked_add(bytes).filter(|n| *n <= self.limit)).map(|_| ())
    }

    /// Grants `bytes` for `what`, or says why not (naming the flag that sets the budget).
    pub fn grant(self: &Arc<Self>, bytes: u64, what: &str) -> Result<MemoryGrant, String> {
        self.take(bytes).map_err(|used| self.refusal(bytes, used, what))?;
        Ok(MemoryGrant { budget: self.clone(), bytes })
    }

    fn refusal(&self, bytes: u64, used: u64, what: &str) -> String {
        format!(
            "{what} needs {} of memory; {} of this server's {} are in use by other sessions (--max-memory-mib)",
            mib(bytes),
            mib(used),
            mib(self.limit)
        )
    }
}

/// Memory granted to one session; returned to the budget when dropped.
#[derive(Debug)]
pub struct MemoryGrant {
    budget: Arc<MemoryBudget>,
    bytes: u64,
}

impl MemoryGrant {
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Changes the grant to `bytes` (a settings change that needs more or less); on
    /// refusal the grant stays as it was.
    pub fn resize(&mut self, bytes: u64, what: &str) -> Result<(), String> {
        if bytes > self.bytes {
            let more = bytes - self.bytes;
            self.budget.take(more).map_err(|used| self.budget.refusal(bytes, used - self.bytes, what))?;
        } else {
            self.budget.used.fetch_sub(self.bytes - bytes, Ordering::SeqCst);
        }
        self.bytes = bytes;
        Ok(())
    }
}

impl Drop for MemoryGrant {
    fn drop(&mut self) {
        self.budget.used.fetch_sub(self.bytes, Ordering::SeqCst);
    }
}

/// The default budget: half of the memory this process may use — the machine's, or its
/// container's limit (cgroup v2 `memory.max` or v1 `memory.limit_in_bytes`) when smaller —
/// leaving the rest for scenes, their edge indexes and everything else; 8 GiB where neither
/// can be read.
pub fn default_budget_bytes() -> u64 {
    let machine = std::fs::read_to_string("/proc/meminfo").ok().and_then(|t| {
        t.lines().find_map(|l| l.strip_prefix("MemTotal:").and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok()))
    });
    let machine = machine.map(|kib| kib * 1024);
    let container = ["/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"]
        .iter()
        .find_map(|p| std::fs::read_to_string(p).ok().and_then(|t| t.trim().parse::<u64>().ok()));
    match (machine, container) {
        (Some(m), Some(c)) => m.min(c) / 2,
        (Some(m), None) => m / 2,
        (None, Some(c)) => c / 2,
        (None, None) => 8 << 30,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grants_add_up_resize_and_return() {
        let b = MemoryBudget::new(1000);
        let a = b.grant(600, "a 10x10 session").unwrap();
        let e = b.grant(500, "a 20x20 session").unwrap_err();
        assert!(e.contains("a 20x20 session") && e.contains("--max-memory-mib"), "{e}");
        let mut c = b.grant(400, "c").unwrap();
        assert_eq!(b.used(), 1000);
        assert!(c.resize(401, "c grown").is_err());
        assert_eq!((b.used(), c.bytes()), (1000, 400), "a refused resize changes nothing");
        c.resize(100, "c shrunk").unwrap();
        assert_eq!(b.used(), 700);
        drop(a);
        drop(c);
        assert_eq!(b.used(), 0);
        assert!(MemoryBudget::unlimited().grant(u64::MAX / 2, "x").is_ok());
        assert!(default_budget_bytes() >= 1 << 28);
    }

    #[test]
    fn the_estimate_grows_with_the_image_and_the_settings() {
        let s = SessionSettings::default();
        let small = SessionMemory::estimate(512, 512, 2.0, &s, 2).total();
        let big = SessionMemory::estimate(4096, 4096, 2.0, &s, 2).total();
        assert!(big > 60 * small && big < 68 * small, "{small} {big}");
        let dense = SessionSettings { sparseness: 1.0, ..s };
        assert!(SessionMemory::estimate(512, 512, 2.0, &dense, 2).total() > small + 64 * 512 * 512, "sampling every pixel needs a bigger ring");
    }
}
