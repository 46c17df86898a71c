//! Changed-tile frames for the browser viewer (issue 16 item 3; no paper section: a transport of the frames of paper 000 §3):
//! a frame is cut into [`TILE`]×[`TILE`] tiles, compared with the last frame sent to the same
//! page, and only the tiles that differ travel, their sRGB bytes concatenated and deflated
//! (zlib) in one block the page inflates with the browser's own `DecompressionStream`.
//!
//! Wire layout of one binary WebSocket message: `u32` little-endian length of a JSON header,
//! the header (frame number, size, the changed tiles' indices in row-major tile order, the
//! frame's stats), then the zlib block: for each listed tile, its rows of `w × 3` bytes
//! (tiles on the right and bottom edges are cut to the frame).
use flate2::write::ZlibEncoder;
use flate2::Compression;
use std::io::Write;

/// Tile side in pixels: small enough that a moving object changes few of them, large enough
/// that the list of indices stays short beside the pixels.
pub const TILE: u32 = 32;

/// The frame last sent to one page, to diff the next one against.
#[derive(Debug, Default)]
pub struct TileDiff {
    width: u32,
    height: u32,
    last: Vec<u8>,
}

/// One frame's changed tiles, deflated.
#[derive(Debug, Clone, PartialEq)]
pub struct TileUpdate {
    /// Row-major tile indices (`ty * tiles_x + tx`) of the tiles in `deflated`, ascending.
    pub tiles: Vec<u32>,
    /// zlib block of the listed tiles' RGB rows.
    pub deflated: Vec<u8>,
    /// The listed tiles' bytes before deflate.
    pub raw_bytes: usize,
}

/// Tiles across and down a `width` × `height` frame.
pub fn tile_grid(width: u32, height: u32) -> (u32, u32) {
    (width.div_ceil(TILE), height.div_ceil(TILE))
}

/// Pixel rectangle `(x0, y0, w, h)` of tile `index` in a frame of `width` × `height`.
pub fn tile_rect(index: u32, width: u32, height: u32) -> (u32, u32, u32, u32) {
    let (tx_n, _) = tile_grid(width, height);
    let (tx, ty) = (index % tx_n, index / tx_n);
    let (x0, y0) = (tx * TILE, ty * TILE);
    (x0, y0, TILE.min(width - x0), TILE.min(height - y0))
}

impl TileDiff {
    /// Forgets the last frame: the next update sends every tile (a new page, a new session).
    pub fn reset(&mut self) {
        self.last.clear();
    }

    /// The tiles of `rgb` (`width` × `height` × 3 sRGB bytes) that differ from the last frame
    /// given here (all of them after a size change or [`Self::reset`]); remembers `rgb`.
    /// `rgb` of the wrong length is an error, never a panic.
    pub fn update(&mut self, rgb: &[u8], width: u32, height: u32) -> Result<TileUpdate, String> {
        let want = width as usize * height as usize * 3;
        if rgb.len() != want || width == 0 || height == 0 {
            return Err(format!("a {width}x{height} RGB frame needs {want} bytes, got {}", rgb.len()));
        }
        let fresh = self.width != width || self.height != height || self.last.len() != want;
        let (tx_n, ty_n) = tile_grid(width, height);
        let mut tiles = Vec::new();
        let mut raw = Vec::new();
        let stride = width as usize * 3;
        for index in 0..tx_n * ty_n {
            let (x0, y0, w, h) = tile_rect(index, width, height);
            let rows = (y0..y0 + h).map(|y| {
                let start = y as usize * stride + x0 as usize * 3;
                start..start + w as usize * 3
            });
            let changed = fresh || rows.clone().any(|r| rgb[r.clone()] != self.last[r]);
            if changed {
                tiles.push(index);
                for r in rows {
                    raw.extend_from_slice(&rgb[r]);
                }
            }
        }
        self.width = width;
        self.height = height;
        self.last.clear();
        self.last.extend_from_slice(rgb);
        // Level 1: the fastest deflate; on rendered frames it keeps most of the gain of the
        // default level (measured in the README's "Remote viewing in a browser").
        let mut z = ZlibEncoder::new(Vec::with_capacity(raw.len() / 3 + 64), Compression::fast());
        z.write_all(&raw).map_err(|e| format!("deflate: {e}"))?;
        let deflated = z.finish().map_err(|e| format!("deflate: {e}"))?;
        Ok(TileUpdate { tiles, deflated, raw_bytes: raw.len() })
    }
}

/// One binary message: header length, JSON header, zlib block (see the module doc).
pub fn frame_message(header: &serde_json::Value, deflated: &[u8]) -> Vec<u8> {
    let head = header.to_string();
    let mut out = Vec::with_capacity(4 + head.len() + deflated.len());
    out.extend_from_slice(&(head.len() as u32).to_le_bytes());
    out.extend_from_slice(head.as_bytes());
    out.extend_from_slice(deflated);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use flate2::read::ZlibDecoder;
    use std::io::Read;

    /// The page's side of the protocol, as the oracle: paints the listed tiles of `u` into
    /// `img`.
    fn apply(img: &mut [u8], u: &TileUpdate, width: u32, height: u32) {
        let mut raw = Vec::new();
        ZlibDecoder::new(&u.deflated[..]).read_to_end(&mut raw).unwrap();
        assert_eq!(raw.len(), u.raw_bytes);
        let mut at = 0;
        for &i in &u.tiles {
            let (x0, y0, w, h) = tile_rect(i, width, height);
            for y in y0..y0 + h {
                let s = (y * width + x0) as usize * 3;
                img[s..s + w as usize * 3].copy_from_slice(&raw[at..at + w as usize * 3]);
                at += w as usize * 3;
            }
        }
        assert_eq!(at, raw.len(), "every byte belongs to a listed tile");
    }

    fn frame(width: u32, height: u32, seed: u32) -> Vec<u8> {
        (0..width * height * 3).map(|i| (i.wrapping_mul(2654435761).wrapping_add(seed) >> 7) as u8).collect()
    }

    #[test]
    fn only_changed_tiles_travel_and_the_page_rebuilds_the_frame_exactly() {
        // 70 × 45: edge tiles are cut (70 = 2·32 + 6, 45 = 32 + 13), 3 × 2 tiles.
        let (w, h) = (70, 45);
        assert_eq!(tile_grid(w, h), (3, 2));
        assert_eq!(tile_rect(5, w, h), (64, 32, 6, 13));
        let mut diff = TileDiff::default();
        let mut page = vec![0u8; (w * h * 3) as usize];
        let a = frame(w, h, 1);
        let u = diff.update(&a, w, h).unwrap();
        assert_eq!(u.tiles, (0..6).collect::<Vec<_>>(), "the first frame sends every tile");
        assert_eq!(u.raw_bytes, a.len());
        apply(&mut page, &u, w, h);
        assert_eq!(page, a);

        // Unchanged: nothing but an empty block.
        let u = diff.update(&a, w, h).unwrap();
        assert!(u.tiles.is_empty() && u.raw_bytes == 0);
        apply(&mut page, &u, w, h);

        // One pixel in tile (2, 1) and one in tile (0, 0) change: exactly those two travel.
        let mut b = a.clone();
        let px = |x: u32, y: u32| ((y * w + x) * 3) as usize;
        b[px(69, 44) + 2] ^= 0xff;
        b[px(31, 31)] ^= 1;
        let u = diff.update(&b, w, h).unwrap();
        assert_eq!(u.tiles, vec![0, 5]);
        assert_eq!(u.raw_bytes, (32 * 32 + 6 * 13) * 3);
        apply(&mut page, &u, w, h);
        assert_eq!(page, b);

        // A size change or a reset sends everything again.
        let c = frame(40, 40, 2);
        assert_eq!(diff.update(&c, 40, 40).unwrap().tiles.len(), 4);
        diff.reset();
        assert_eq!(diff.update(&c, 40, 40).unwrap().tiles.len(), 4);
    }

    #[test]
    fn a_frame_of_the_wrong_size_is_an_error() {
        let mut diff = TileDiff::default();
        let e = diff.update(&[0; 10], 2, 2).unwrap_err();
        assert!(e.contains("2x2") && e.contains("12 bytes") && e.contains("got 10"), "{e}");
        assert!(diff.update(&[], 0, 5).is_err());
    }

    #[test]
    fn the_message_carries_header_then_block() {
        let m = frame_message(&serde_json::json!({"seq": 7}), &[1, 2, 3]);
        let n = u32::from_le_bytes(m[..4].try_into().unwrap()) as usize;
        assert_eq!(&m[4..4 + n], br#"{"seq":7}"#);
        assert_eq!(&m[4 + n..], &[1, 2, 3]);
    }
}
