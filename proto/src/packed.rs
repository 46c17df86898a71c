//! Fixed-size little-endian records for the shading traffic between the renderer and its
//! workers (`RequestBatch.packed_requests`, `SampleBatch.packed_samples`).
//!
//! Why: at rest the renderer sends and receives tens of thousands of requests and samples a
//! second on the same two cores its frame loop runs on. As protobuf messages each sample is
//! a walk over varints and five nested `Vec3` messages (a `perf` profile of the server at
//! rest: 10 % of its CPU decoding samples, 3 % encoding requests); as records it is a copy.
//! The records carry every field of the messages, so unpacking gives back exactly the
//! messages that were packed (the presence of each optional vector included), and every
//! consumer keeps reading `requests` and `samples`.
use crate::v1::{SampleBatch, RequestBatch, Sample, ShadeRequest, Vec3};

/// Bytes of one packed [`ShadeRequest`]: id, pixel x and y, origin, direction, part, parts.
pub const REQUEST_BYTES: usize = 8 + 4 + 4 + 12 + 12 + 4 + 4;
/// Bytes of one packed [`Sample`]: id, flags, object, triangle, part, distance, and five
/// vectors (position, normal, rgb, local position, local normal).
pub const SAMPLE_BYTES: usize = 8 + 4 * 5 + 12 * 5;

const HIT: u32 = 1;
/// Presence bits of the optional vectors, in record order.
const HAS: [u32; 5] = [1 << 1, 1 << 2, 1 << 3, 1 << 4, 1 << 5];

/// Why packed records could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PackedError {
    #[error("packed {what} are {len} bytes, not a whole number of {record}-byte records")]
    Length { what: &'static str, len: usize, record: usize },
    #[error("a batch holds both packed and unpacked {what}")]
    Both { what: &'static str },
}

struct Writer<'a>(&'a mut Vec<u8>);

impl Writer<'_> {
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }
    fn vec3(&mut self, v: &Option<Vec3>) {
        let v = v.unwrap_or_default();
        self.f32(v.x);
        self.f32(v.y);
        self.f32(v.z);
    }
}

/// Reads one record; the record's length is checked by the caller.
struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn u32(&mut self) -> u32 {
        let v = u32::from_le_bytes(self.b[self.at..self.at + 4].try_into().expect("4 bytes"));
        self.at += 4;
        v
    }
    fn u64(&mut self) -> u64 {
        let v = u64::from_le_bytes(self.b[self.at..self.at + 8].try_into().expect("8 bytes"));
        self.at += 8;
        v
    }
    fn f32(&mut self) -> f32 {
        f32::from_bits(self.u32())
    }
    fn vec3(&mut self) -> Vec3 {
        Vec3 { x: self.f32(), y: self.f32(), z: self.f32() }
    }
}

fn records<'a>(bytes: &'a [u8], record: usize, what: &'static str) -> Result<std::slice::ChunksExact<'a, u8>, PackedError> {
    if bytes.len() % record != 0 {
        return Err(PackedError::Length { what, len: bytes.len(), record });
    }
    Ok(bytes.chunks_exact(record))
}

/// Packs requests into `out` (appended).
pub fn pack_requests(requests: &[ShadeRequest], out: &mut Vec<u8>) {
    out.reserve(requests.len() * REQUEST_BYTES);
    let mut w = Writer(out);
    for r in requests {
        w.u64(r.id);
        w.u32(r.pixel_x);
        w.u32(r.pixel_y);
        w.vec3(&r.origin);
        w.vec3(&r.direction);
        w.u32(r.part);
        w.u32(r.parts);
    }
}

/// Reads packed requests. The vectors of a packed request are always present.
pub fn unpack_requests(bytes: &[u8]) -> Result<Vec<ShadeRequest>, PackedError> {
    // Sized from the bytes that arrived, not from a count the message claims.
    Ok(records(bytes, REQUEST_BYTES, "requests")?
        .map(|rec| {
            let mut r = Reader { b: rec, at: 0 };
            ShadeRequest {
                id: r.u64(),
                pixel_x: r.u32(),
                pixel_y: r.u32(),
                origin: Some(r.vec3()),
                direction: Some(r.vec3()),
                part: r.u32(),
                parts: r.u32(),
            }
        })
        .collect())
}

/// Packs samples into `out` (appended).
pub fn pack_samples(samples: &[Sample], out: &mut Vec<u8>) {
    out.reserve(samples.len() * SAMPLE_BYTES);
    let mut w = Writer(out);
    for s in samples {
        let vectors = [&s.position, &s.normal, &s.rgb, &s.local_position, &s.local_normal];
        let flags = vectors.iter().zip(HAS).filter(|(v, _)| v.is_some()).fold(if s.hit { HIT } else { 0 }, |f, (_, bit)| f | bit);
        w.u64(s.id);
        w.u32(flags);
        w.u32(s.object_id);
        w.u32(s.triangle);
        w.u32(s.part);
        w.f32(s.distance);
        for v in vectors {
            w.vec3(v);
        }
    }
}

/// Reads packed samples.
pub fn unpack_samples(bytes: &[u8]) -> Result<Vec<Sample>, PackedError> {
    Ok(records(bytes, SAMPLE_BYTES, "samples")?
        .map(|rec| {
            let mut r = Reader { b: rec, at: 0 };
            let id = r.u64();
            let flags = r.u32();
            let (object_id, triangle, part, distance) = (r.u32(), r.u32(), r.u32(), r.f32());
            let mut v = [None; 5];
            for (slot, bit) in v.iter_mut().zip(HAS) {
                let x = r.vec3();
                *slot = (flags & bit != 0).then_some(x);
            }
            let [position, normal, rgb, local_position, local_normal] = v;
            Sample { id, hit: flags & HIT != 0, position, normal, object_id, distance, rgb, triangle, local_position, local_normal, part }
        })
        .collect())
}

/// Moves a batch's packed requests into `requests` (a batch with neither or only
/// `requests` is left as it is).
pub fn unpack_request_batch(b: &mut RequestBatch) -> Result<(), PackedError> {
    unpack_into(&mut b.packed_requests, &mut b.requests, "requests", unpack_requests)
}

/// Moves a batch's packed samples into `samples`.
pub fn unpack_sample_batch(b: &mut SampleBatch) -> Result<(), PackedError> {
    unpack_into(&mut b.packed_samples, &mut b.samples, "samples", unpack_samples)
}

/// Replaces `unpacked` by the records of `packed` (emptied), unless there are none; a
/// batch may hold one form or the other, not both.
fn unpack_into<T>(
    packed: &mut Vec<u8>,
    unpacked: &mut Vec<T>,
    what: &'static str,
    unpack: fn(&[u8]) -> Result<Vec<T>, PackedError>,
) -> Result<(), PackedError> {
    if packed.is_empty() {
        return Ok(());
    }
    if !unpacked.is_empty() {
        return Err(PackedError::Both { what });
    }
    *unpacked = unpack(packed)?;
    *packed = Vec::new();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;

    fn v(x: f32, y: f32, z: f32) -> Option<Vec3> {
        Some(Vec3 { x, y, z })
    }

    fn requests() -> Vec<ShadeRequest> {
        (0..5u32)
            .map(|i| ShadeRequest {
                id: u64::MAX - i as u64,
                pixel_x: i * 7,
                pixel_y: u32::MAX - i,
                origin: v(i as f32, -0.0, f32::MIN_POSITIVE),
                direction: v(1e30, f32::INFINITY, -(i as f32) / 3.0),
                part: i % 3,
                parts: 3,
            })
            .collect()
    }

    fn samples() -> Vec<Sample> {
        let hit = Sample {
            id: 1 << 40,
            hit: true,
            position: v(1.5, -2.25, 3.0),
            normal: v(0.0, 1.0, 0.0),
            object_id: 3,
            distance: 4.75,
            rgb: v(0.1, 0.2, f32::NAN),
            triangle: 123_456,
            local_position: v(-1.0, 0.5, 2.0),
            local_normal: v(0.6, 0.0, 0.8),
            part: 2,
        };
        let miss = Sample { id: 9, hit: false, rgb: v(0.3, 0.3, 0.3), object_id: u32::MAX, ..Default::default() };
        // Presence of each vector on its own.
        let partial = Sample { id: 10, hit: true, normal: v(1.0, 0.0, 0.0), local_normal: v(0.0, 0.0, -1.0), ..Default::default() };
        vec![hit, miss, partial]
    }

    /// Bitwise equality (NaN included) through the protobuf encoding.
    fn same<M: Message>(a: &[M], b: &[M]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.encode_to_vec() == y.encode_to_vec())
    }

    #[test]
    fn requests_round_trip_exactly() {
        let r = requests();
        let mut bytes = Vec::new();
        pack_requests(&r, &mut bytes);
        assert_eq!(bytes.len(), r.len() * REQUEST_BYTES);
        assert!(same(&unpack_requests(&bytes).unwrap(), &r));
    }

    #[test]
    fn samples_round_trip_exactly_with_absent_vectors() {
        let s = samples();
        let mut bytes = Vec::new();
        pack_samples(&s, &mut bytes);
        assert_eq!(bytes.len(), s.len() * SAMPLE_BYTES);
        let back = unpack_samples(&bytes).unwrap();
        assert!(same(&back, &s));
        assert!(back[1].position.is_none() && back[1].rgb.is_some());
        assert!(back[2].position.is_none() && back[2].local_normal.is_some());
    }

    #[test]
    fn packed_is_smaller_than_the_messages() {
        let s = samples();
        let mut bytes = Vec::new();
        pack_samples(&s[..1], &mut bytes);
        let msg = SampleBatch { samples: s[..1].to_vec(), ..Default::default() }.encode_to_vec();
        assert!(bytes.len() < msg.len(), "{} packed vs {} as a message", bytes.len(), msg.len());
    }

    #[test]
    fn torn_records_and_mixed_batches_are_refused() {
        let mut bytes = Vec::new();
        pack_samples(&samples(), &mut bytes);
        bytes.pop();
        assert_eq!(unpack_samples(&bytes), Err(PackedError::Length { what: "samples", len: 3 * SAMPLE_BYTES - 1, record: SAMPLE_BYTES }));
        assert!(matches!(unpack_requests(&[0; REQUEST_BYTES + 1]), Err(PackedError::Length { .. })));
        let mut b = RequestBatch { requests: requests(), packed_requests: vec![0; REQUEST_BYTES], ..Default::default() };
        assert_eq!(unpack_request_batch(&mut b), Err(PackedError::Both { what: "requests" }));
        let mut b = SampleBatch { samples: samples(), packed_samples: vec![0; SAMPLE_BYTES], ..Default::default() };
        assert_eq!(unpack_sample_batch(&mut b), Err(PackedError::Both { what: "samples" }));
    }

    #[test]
    fn unpacking_a_batch_moves_its_records() {
        let mut b = RequestBatch { batch_id: 4, ..Default::default() };
        pack_requests(&requests(), &mut b.packed_requests);
        unpack_request_batch(&mut b).unwrap();
        assert!(b.packed_requests.is_empty() && same(&b.requests, &requests()));
        let mut b = SampleBatch::default();
        unpack_sample_batch(&mut b).unwrap();
        assert!(b.samples.is_empty(), "an empty batch stays empty");
    }
}
