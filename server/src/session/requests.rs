//! Outgoing sample requests and the bookkeeping that turns answers back into Render Cache
//! points (paper 000 §4.3: "the shader computes the color and first point of intersection
//! for a viewing ray").
//!
//! A worker answers a request with its id only, yet the cache needs the pixel the sample was
//! shaded for and, for a ray that hit nothing, the ray direction (a miss is a point at
//! infinity). Both are remembered in a ring indexed by request id: no hashing, no
//! allocation per request, and an answer whose slot was reused (it came back very late)
//! is recognised by its id and ignored.
use crate::rng::mix64;
use crate::sampling::PixelRequest;
use edgepoint_proto as pb;
use edgepoint_scene::camera::CameraFrame;
use glam::Vec3;
use rayon::prelude::*;

#[derive(Debug, Clone, Copy)]
struct Slot {
    id: u64,
    pixel: [u32; 2],
    dir: Vec3,
    point: u32,
}

const EMPTY: Slot = Slot { id: u64::MAX, pixel: [0, 0], dir: Vec3::ZERO, point: u32::MAX };

/// What the session remembers of one request.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RequestInfo {
    pub pixel: [u32; 2],
    pub dir: Vec3,
    /// The cached point the request shades again (`u32::MAX`: none; see
    /// `sampling::aim_at_points`).
    pub point: u32,
}

/// Request ids to (pixel, direction), for the most recent `capacity` requests.
pub struct RequestRing {
    slots: Vec<Slot>,
    mask: u64,
    next_id: u64,
}

impl RequestRing {
    /// Bytes of a ring remembering at least `min_capacity` requests.
    pub fn bytes_for(min_capacity: usize) -> usize {
        min_capacity.max(64).next_power_of_two() * std::mem::size_of::<Slot>()
    }

    /// A ring remembering at least `min_capacity` requests.
    pub fn new(min_capacity: usize) -> Self {
        let cap = min_capacity.max(64).next_power_of_two();
        RequestRing { slots: vec![EMPTY; cap], mask: cap as u64 - 1, next_id: 0 }
    }

    pub fn capacity(&self) -> usize {
        self.slots.len()
    }

    /// Grows the ring (keeping what it remembers) so it holds at least `min_capacity`.
    pub fn reserve(&mut self, min_capacity: usize) {
        if min_capacity <= self.slots.len() {
            return;
        }
        let mut bigger = RequestRing::new(min_capacity);
        bigger.next_id = self.next_id;
        for s in self.slots.iter().filter(|s| s.id != u64::MAX) {
            bigger.slots[(s.id & bigger.mask) as usize] = *s;
        }
        *self = bigger;
    }

    /// Records a request (aimed at cached point `point`, `u32::MAX` for none); returns its id.
    #[inline]
    pub fn push(&mut self, pixel: [u32; 2], dir: Vec3, point: u32) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        self.slots[(id & self.mask) as usize] = Slot { id, pixel, dir, point };
        id
    }

    /// The id the next [`Self::push`] returns.
    pub fn next_id(&self) -> u64 {
        self.next_id
    }

    /// What request `id` was, unless its slot has been reused since.
    #[inline]
    pub fn get(&self, id: u64) -> Option<RequestInfo> {
        let s = self.slots[(id & self.mask) as usize];
        (s.id == id).then_some(RequestInfo { pixel: s.pixel, dir: s.dir, point: s.point })
    }
}

/// Per-batch constants for request building.
pub struct BatchSpec<'a> {
    pub epoch: u64,
    pub shader: &'a str,
    pub params: &'a std::collections::HashMap<String, f64>,
    pub batch_size: usize,
    /// Parts per sample (split shading, paper 004 §4.4; 1: whole pixels).
    pub parts: u32,
    /// Batches of neighbouring picks instead of picks spread over the image (see
    /// [`build_batches`]).
    pub coherent: bool,
}

/// Turns the pixels the sampler chose into ray request batches through `cam`, recording
/// each request in `ring`. `next_batch_id` and `seed` advance per batch.
///
/// The picks come in scan order; batch `b` of `n` takes every `n`-th pick starting at `b`,
/// so every batch spreads over the whole image. Answers arrive batch by batch, and the
/// first to arrive then already cover the whole frame: a session's first frame is coarse
/// but complete instead of a band of the top rows, and after a fast move the newly exposed
/// regions everywhere get their first samples at once.
///
/// `spec.coherent` (a still view, converging): batch `b` takes the `b`-th run of consecutive
/// picks instead, neighbouring pixels, whose rays share the worker's BVH nodes and
/// irradiance records in its caches; at rest every batch of a round arrives long before the
/// image is next looked at, so nothing is lost by it.
///
/// Split shading (`spec.parts` > 1): each batch goes out as `parts` sibling batches, one
/// per part, with the same requests, ids and seed (so the parts draw the random numbers of
/// one whole shading and add up to it) and consecutive batch ids; siblings are queued one
/// after another so that different workers take them at the same time.
pub fn build_batches(
    picks: &[PixelRequest],
    cam: &CameraFrame,
    ring: &mut RequestRing,
    spec: &BatchSpec<'_>,
    next_batch_id: &mut u64,
    seed: &mut u64,
    out: &mut Vec<pb::RequestBatch>,
) {
    let batches = picks.len().div_ceil(spec.batch_size.max(1));
    // The rays of the batches in parallel (a ray per pick is most of the work), then the
    // ring in order: batch b's requests take the ids after those of the batches before it.
    let first_id = ring.next_id();
    let (base, extra) = (picks.len() / batches.max(1), picks.len() % batches.max(1));
    let start = |b: usize| first_id + (b * base + b.min(extra)) as u64;
    let mut all: Vec<Vec<pb::ShadeRequest>> = Vec::with_capacity(batches);
    let batch_picks = |b: usize| -> std::iter::StepBy<std::iter::Skip<std::slice::Iter<'_, PixelRequest>>> {
        if spec.coherent {
            let (from, to) = ((start(b) - first_id) as usize, (start(b + 1) - first_id) as usize);
            picks[from..to].iter().skip(0).step_by(1)
        } else {
            picks.iter().skip(b).step_by(batches)
        }
    };
    (0..batches)
        .into_par_iter()
        .map(|b| {
            batch_picks(b)
                .enumerate()
                .map(|(j, p)| {
                    let (origin, dir) = cam.ray(p.sx, p.sy);
                    pb::ShadeRequest { id: start(b) + j as u64, pixel_x: p.x, pixel_y: p.y, origin: Some(origin.into()), direction: Some(dir.into()), ..Default::default() }
                })
                .collect()
        })
        .collect_into_vec(&mut all);
    for (b, requests) in all.iter().enumerate() {
        for (r, p) in requests.iter().zip(batch_picks(b)) {
            let dir = r.direction.map_or(Vec3::ZERO, Vec3::from);
            let id = ring.push([p.x, p.y], dir, p.point);
            debug_assert_eq!(id, r.id);
        }
    }
    for requests in all {
        *seed = mix64(*seed);
        let whole = pb::RequestBatch {
            batch_id: *next_batch_id,
            epoch: spec.epoch,
            shader: spec.shader.to_string(),
            params: spec.params.clone(),
            requests,
            seed: *seed,
            // Packed by the worker link on the way out.
            packed_requests: Vec::new(),
        };
        *next_batch_id += 1;
        if spec.parts <= 1 {
            out.push(whole);
            continue;
        }
        for part in 1..spec.parts {
            let mut b = whole.clone();
            b.batch_id = *next_batch_id;
            *next_batch_id += 1;
            for r in &mut b.requests {
                (r.part, r.parts) = (part, spec.parts);
            }
            out.push(b);
        }
        let mut first = whole;
        for r in &mut first.requests {
            (r.part, r.parts) = (0, spec.parts);
        }
        // Part 0 (emission, ambient, indirect light: usually the largest) first.
        let at = out.len() - (spec.parts as usize - 1);
        out.insert(at, first);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_scene::Camera;

    #[test]
    fn ring_remembers_recent_requests_and_forgets_reused_slots() {
        let mut r = RequestRing::new(100);
        assert_eq!(r.capacity(), 128);
        let ids: Vec<u64> = (0..200).map(|i| r.push([i, i + 1], Vec3::new(i as f32, 0.0, 1.0), i)).collect();
        assert_eq!(ids, (0..200).collect::<Vec<_>>());
        for &id in &ids[..72] {
            assert!(r.get(id).is_none(), "slot of {id} was reused");
        }
        for &id in &ids[72..] {
            let info = r.get(id).unwrap();
            assert_eq!(info.pixel, [id as u32, id as u32 + 1]);
            assert_eq!(info.dir.x, id as f32);
            assert_eq!(info.point, id as u32);
        }
        assert!(r.get(500).is_none(), "future id");
        r.reserve(1000);
        assert_eq!(r.capacity(), 1024);
        for &id in &ids[72..] {
            assert_eq!(r.get(id).unwrap().pixel[0], id as u32, "kept across growth");
        }
        assert_eq!(r.push([0, 0], Vec3::Z, u32::MAX), 200);
    }

    #[test]
    fn batches_carry_rays_through_the_picked_positions() {
        let cam = Camera { eye: Vec3::new(0.0, 0.0, 5.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0 };
        let f = cam.frame(32, 16);
        let picks: Vec<PixelRequest> = (0..10).map(|i| PixelRequest { x: i, y: i % 16, sx: i as f32 + 0.25, sy: (i % 16) as f32 + 0.75, point: i }).collect();
        let mut ring = RequestRing::new(64);
        let params = std::collections::HashMap::from([("ambient".to_string(), 0.1)]);
        let spec = BatchSpec { epoch: 3, shader: "direct", params: &params, batch_size: 4, parts: 1, coherent: false };
        let (mut next, mut seed, mut out) = (7u64, 1u64, Vec::new());
        build_batches(&picks, &f, &mut ring, &spec, &mut next, &mut seed, &mut out);
        assert_eq!(out.iter().map(|b| b.requests.len()).collect::<Vec<_>>(), vec![4, 3, 3]);
        // Interleaved: each batch takes every third pick.
        assert_eq!(out[0].requests.iter().map(|r| r.pixel_x).collect::<Vec<_>>(), vec![0, 3, 6, 9]);
        assert_eq!(out[1].requests.iter().map(|r| r.pixel_x).collect::<Vec<_>>(), vec![1, 4, 7]);
        assert_eq!(out.iter().map(|b| b.batch_id).collect::<Vec<_>>(), vec![7, 8, 9]);
        assert_eq!(next, 10);
        assert!(out[0].seed != out[1].seed);
        for b in &out {
            assert_eq!((b.epoch, b.shader.as_str(), b.params.get("ambient")), (3, "direct", Some(&0.1)));
            for r in &b.requests {
                let info = ring.get(r.id).unwrap();
                assert_eq!(info.pixel, [r.pixel_x, r.pixel_y]);
                assert_eq!(info.point, r.pixel_x, "the point the pick was aimed at");
                let d: Vec3 = r.direction.unwrap().into();
                let o: Vec3 = r.origin.unwrap().into();
                // The ray projects back onto the jittered position it was built for.
                let p = picks.iter().find(|p| p.x == r.pixel_x).unwrap();
                let (sx, sy, _) = f.project(o + d * 2.0).unwrap();
                assert!((sx - p.sx).abs() < 1e-3 && (sy - p.sy).abs() < 1e-3);
                assert!((info.dir - d).length() < 1e-6);
                assert_eq!((r.part, r.parts), (0, 0), "whole pixels");
            }
        }
    }

    #[test]
    fn coherent_batches_take_runs_of_neighbouring_picks_with_the_same_ids() {
        let cam = Camera { eye: Vec3::new(0.0, 0.0, 5.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0 };
        let f = cam.frame(32, 16);
        let picks: Vec<PixelRequest> = (0..10).map(|i| PixelRequest { x: i, y: 3, sx: i as f32 + 0.5, sy: 3.5, point: i }).collect();
        let params = std::collections::HashMap::new();
        let mut out = [Vec::new(), Vec::new()];
        for (coherent, out) in [false, true].into_iter().zip(&mut out) {
            let spec = BatchSpec { epoch: 0, shader: "direct", params: &params, batch_size: 4, parts: 1, coherent };
            let (mut ring, mut next, mut seed) = (RequestRing::new(64), 0u64, 1u64);
            build_batches(&picks, &f, &mut ring, &spec, &mut next, &mut seed, out);
            for r in out.iter().flat_map(|b| &b.requests) {
                assert_eq!(ring.get(r.id).unwrap().pixel, [r.pixel_x, 3], "the ring follows the batches");
            }
        }
        let xs = |b: &pb::RequestBatch| b.requests.iter().map(|r| r.pixel_x).collect::<Vec<_>>();
        assert_eq!(out[1].iter().map(xs).collect::<Vec<_>>(), vec![vec![0, 1, 2, 3], vec![4, 5, 6], vec![7, 8, 9]]);
        let ids = |o: &[pb::RequestBatch]| o.iter().map(|b| b.requests.iter().map(|r| r.id).collect::<Vec<_>>()).collect::<Vec<_>>();
        assert_eq!(ids(&out[0]), ids(&out[1]), "same sizes and ids, other pixels");
        assert_eq!(out[0].iter().map(xs).collect::<Vec<_>>()[0], vec![0, 3, 6, 9]);
    }

    #[test]
    fn split_batches_are_siblings_with_one_seed_and_every_part() {
        let cam = Camera { eye: Vec3::new(0.0, 0.0, 5.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0 };
        let f = cam.frame(32, 16);
        let picks: Vec<PixelRequest> = (0..10).map(|i| PixelRequest { x: i, y: 0, sx: i as f32 + 0.5, sy: 0.5, point: u32::MAX }).collect();
        let params = std::collections::HashMap::new();
        let spec = BatchSpec { epoch: 0, shader: "direct", params: &params, batch_size: 4, parts: 3, coherent: false };
        let (mut ring, mut next, mut seed, mut out) = (RequestRing::new(64), 0u64, 1u64, Vec::new());
        build_batches(&picks, &f, &mut ring, &spec, &mut next, &mut seed, &mut out);
        assert_eq!(out.len(), 9, "three batches of picks, three parts each");
        assert_eq!(out.iter().map(|b| b.batch_id).collect::<Vec<_>>(), (0..9).collect::<Vec<_>>());
        for (g, group) in out.chunks(3).enumerate() {
            for (i, b) in group.iter().enumerate() {
                assert_eq!(b.seed, group[0].seed, "one seed per sample's parts");
                assert!(b.requests.iter().all(|r| (r.part, r.parts) == (i as u32, 3)), "group {g} batch {i}");
                let ids = |b: &pb::RequestBatch| b.requests.iter().map(|r| r.id).collect::<Vec<_>>();
                assert_eq!(ids(b), ids(&group[0]));
            }
            assert_ne!(group[0].seed, out[(g + 1) % 3 * 3].seed);
        }
        assert_eq!(out.iter().map(|b| b.requests.len()).sum::<usize>(), 30);
        let mut remembered: Vec<u32> = (0..10).map(|id| ring.get(id).unwrap().pixel[0]).collect();
        remembered.sort_unstable();
        assert_eq!(remembered, (0..10).collect::<Vec<_>>(), "each pick remembered once");
        assert!(ring.get(10).is_none());
    }
}
