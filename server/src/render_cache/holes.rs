//! Filling holes: pixels whose whole interpolation window holds no sample (paper 000 §5.3
//! gives them the highest sampling priority, but until samples arrive they would show the
//! background). They take the average of the samples around them at the finest scale that
//! has any: a pyramid of sample sums over 4 x 4, 8 x 8, … pixel cells (pull), read back
//! bilinearly at each hole (push). Both reconstructions use it, the edge-and-point image and
//! the Render Cache baseline, so that comparisons between them measure the edges, not the
//! holes. Cost: one pass over the point image for the pyramid, then work per hole only.
use super::{PointImage, NO_POINT};
use glam::Vec3;
use rayon::prelude::*;

/// Pixels per side of the finest pyramid cell. A hole has no sample within two pixels, so
/// finer cells around it would be empty anyway.
const FINEST: usize = 4;

/// One pyramid level: per cell the sums of (colour, 1) of its samples.
struct Level {
    w: usize,
    h: usize,
    /// Cell side in pixels.
    size: usize,
    cells: Vec<[f32; 4]>,
}

/// The sample pyramid, allocated once per image size.
pub struct HoleFill {
    width: usize,
    height: usize,
    levels: Vec<Level>,
}

impl HoleFill {
    /// Bytes of the pyramid [`Self::new`] allocates for a `width` × `height` image.
    pub fn bytes_for(width: u32, height: u32) -> usize {
        let (w, h) = (width as usize, height as usize);
        let (mut size, mut cells, mut levels) = (FINEST, 0usize, 0usize);
        loop {
            let (lw, lh) = (w.div_ceil(size).max(1), h.div_ceil(size).max(1));
            cells += lw * lh;
            levels += 1;
            if lw == 1 && lh == 1 {
                break;
            }
            size *= 2;
        }
        cells * std::mem::size_of::<[f32; 4]>() + levels.next_power_of_two().max(4) * std::mem::size_of::<Level>()
    }

    pub fn new(width: u32, height: u32) -> Self {
        let (w, h) = (width as usize, height as usize);
        let mut levels = Vec::new();
        let mut size = FINEST;
        loop {
            let (lw, lh) = (w.div_ceil(size).max(1), h.div_ceil(size).max(1));
            levels.push(Level { w: lw, h: lh, size, cells: vec![[0.0; 4]; lw * lh] });
            if lw == 1 && lh == 1 {
                break;
            }
            size *= 2;
        }
        HoleFill { width: w, height: h, levels }
    }

    /// Bytes held (about 1.33 per pixel).
    pub fn bytes(&self) -> usize {
        self.levels.iter().map(|l| l.cells.len() * 16).sum()
    }

    /// Fills every pixel whose bit is set in `holes` (bit rows: `ceil(width / 64)` words per
    /// row) from the samples of `points`; pixels with no sample anywhere keep their colour.
    /// Returns the number of pixels filled.
    pub fn fill(&mut self, points: &PointImage, holes: &[u64], image: &mut [Vec3]) -> u32 {
        let (w, h) = (self.width, self.height);
        let words = w.div_ceil(64);
        if w == 0 || h == 0 || holes.iter().all(|&b| b == 0) {
            return 0;
        }
        self.pull(points);
        let levels = &self.levels;
        if levels.last().is_none_or(|top| top.cells.iter().all(|c| c[3] == 0.0)) {
            return 0;
        }
        image
            .par_chunks_mut(w)
            .zip(holes.par_chunks(words))
            .enumerate()
            .map(|(y, (row, bits))| {
                let mut n = 0;
                for (j, &word) in bits.iter().enumerate() {
                    let mut b = word;
                    while b != 0 {
                        let i = b.trailing_zeros() as usize;
                        b &= b - 1;
                        let x = 64 * j + i;
                        if let Some(c) = push(levels, x, y) {
                            row[x] = c;
                            n += 1;
                        }
                    }
                }
                n
            })
            .sum()
    }

    /// Sums the samples into the finest level, then each level into the next.
    fn pull(&mut self, points: &PointImage) {
        let w = self.width;
        let finest = &mut self.levels[0];
        let lw = finest.w;
        finest.cells.par_chunks_mut(lw).enumerate().for_each(|(cy, cells)| {
            cells.fill([0.0; 4]);
            for y in cy * FINEST..((cy + 1) * FINEST).min(points.height as usize) {
                for x in 0..w {
                    let i = y * w + x;
                    if points.point[i] != NO_POINT {
                        let c = points.color[i];
                        let cell = &mut cells[x / FINEST];
                        cell[0] += c.x;
                        cell[1] += c.y;
                        cell[2] += c.z;
                        cell[3] += 1.0;
                    }
                }
            }
        });
        for l in 1..self.levels.len() {
            let (lower, upper) = self.levels.split_at_mut(l);
            let (src, dst) = (&lower[l - 1], &mut upper[0]);
            for cy in 0..dst.h {
                for cx in 0..dst.w {
                    let mut s = [0f32; 4];
                    for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                        let (sx, sy) = (2 * cx + dx, 2 * cy + dy);
                        if sx < src.w && sy < src.h {
                            let c = src.cells[sy * src.w + sx];
                            for k in 0..4 {
                                s[k] += c[k];
                            }
                        }
                    }
                    dst.cells[cy * dst.w + cx] = s;
                }
            }
        }
    }
}

/// The bilinearly weighted average of the four cells around pixel (x, y) at the finest
/// level where they hold a sample.
fn push(levels: &[Level], x: usize, y: usize) -> Option<Vec3> {
    for l in levels {
        let s = l.size as f32;
        let (u, v) = ((x as f32 + 0.5) / s - 0.5, (y as f32 + 0.5) / s - 0.5);
        let (u0, v0) = (u.floor(), v.floor());
        let (fu, fv) = (u - u0, v - v0);
        let mut acc = [0f32; 4];
        for (dy, wy) in [(0i64, 1.0 - fv), (1, fv)] {
            for (dx, wx) in [(0i64, 1.0 - fu), (1, fu)] {
                let cx = (u0 as i64 + dx).clamp(0, l.w as i64 - 1) as usize;
                let cy = (v0 as i64 + dy).clamp(0, l.h as i64 - 1) as usize;
                let c = l.cells[cy * l.w + cx];
                let wgt = wx * wy;
                for k in 0..4 {
                    acc[k] += wgt * c[k];
                }
            }
        }
        if acc[3] > 1e-6 {
            return Some(Vec3::new(acc[0], acc[1], acc[2]) / acc[3]);
        }
    }
    None
}

/// Filling holes within the surfaces the frame's exact visibility shows
/// (`crate::visibility`): a hole takes its colour from the nearest pixels that show the same
/// object and have a colour (breadth first through the object's hole pixels, each pixel the
/// mean of its already coloured 4-neighbours on the object). Where a box's side has just
/// come into view, it is filled from the box, not from the wall beside it; the background
/// from background samples. Holes on an object with no coloured pixel in their reach are left
/// for [`HoleFill`]. Cost: work per hole pixel only.
#[derive(Default)]
pub struct ObjectFill {
    /// Hole bits still unfilled (a copy of the caller's, cleared as pixels are filled).
    todo: Vec<u64>,
    /// Pixels queued for the current / next round.
    round: Vec<u32>,
    next: Vec<u32>,
    /// Bits of pixels already queued.
    queued: Vec<u64>,
    colours: Vec<Vec3>,
}

impl ObjectFill {
    /// Bytes held (grows with the holes of the frames seen).
    pub fn bytes(&self) -> usize {
        8 * (self.todo.capacity() + self.queued.capacity()) + 4 * (self.round.capacity() + self.next.capacity()) + 12 * self.colours.capacity()
    }

    /// Bytes held at most for a `width` × `height` image: [`Self::fill`] sizes its queues
    /// for every pixel on first use, so they never grow by doubling past this.
    pub fn bytes_for(width: u32, height: u32) -> usize {
        let pixels = width as usize * height as usize;
        16 * height as usize * (width as usize).div_ceil(64) + (4 + 4 + 12) * pixels
    }

    /// Fills the hole pixels (bits in `holes`, `ceil(width / 64)` words per row) reachable
    /// from coloured pixels of the same object (`objects`, per pixel; any id, the background
    /// too). Returns the pixels filled and the hole bits left.
    pub fn fill(&mut self, width: usize, height: usize, holes: &[u64], objects: &[u32], image: &mut [Vec3]) -> (u32, &[u64]) {
        let words = width.div_ceil(64);
        let pixels = width * height;
        for q in [&mut self.round, &mut self.next] {
            q.clear();
            q.reserve_exact(pixels);
        }
        self.colours.clear();
        self.colours.reserve_exact(pixels);
        self.todo.clear();
        self.todo.extend_from_slice(holes);
        self.queued.clear();
        self.queued.resize(self.todo.len(), 0);
        let at = |i: usize| super::pixel_bit(width, i);
        let bit = |v: &[u64], i: usize| v[at(i).0] & at(i).1 != 0;
        let set = |v: &mut [u64], i: usize| v[at(i).0] |= at(i).1;
        let clear = |v: &mut [u64], i: usize| v[at(i).0] &= !at(i).1;
        let neighbours = |i: usize| {
            let (x, y) = (i % width, i / width);
            [
                (x > 0).then(|| i - 1),
                (x + 1 < width).then(|| i + 1),
                (y > 0).then(|| i - width),
                (y + 1 < height).then(|| i + width),
            ]
        };
        // Round 0: holes beside a coloured pixel of their object.
        for (wi, &word) in holes.iter().enumerate() {
            let mut b = word;
            while b != 0 {
                let i = (wi / words) * width + (wi % words) * 64 + b.trailing_zeros() as usize;
                b &= b - 1;
                if neighbours(i).into_iter().flatten().any(|j| !bit(holes, j) && objects[j] == objects[i]) {
                    self.round.push(i as u32);
                    set(&mut self.queued, i);
                }
            }
        }
        let mut filled = 0u32;
        while !self.round.is_empty() {
            // Colours from pixels coloured before this round only, then written at once.
            self.colours.clear();
            for &i in &self.round {
                let i = i as usize;
                let (mut sum, mut n) = (Vec3::ZERO, 0u32);
                for j in neighbours(i).into_iter().flatten() {
                    if !bit(&self.todo, j) && objects[j] == objects[i] {
                        sum += image[j];
                        n += 1;
                    }
                }
                self.colours.push(sum / n.max(1) as f32);
            }
            self.next.clear();
            for (k, &i) in self.round.iter().enumerate() {
                let i = i as usize;
                image[i] = self.colours[k];
                clear(&mut self.todo, i);
                filled += 1;
            }
            for k in 0..self.round.len() {
                let i = self.round[k] as usize;
                for j in neighbours(i).into_iter().flatten() {
                    if bit(&self.todo, j) && !bit(&self.queued, j) && objects[j] == objects[i] {
                        set(&mut self.queued, j);
                        self.next.push(j as u32);
                    }
                }
            }
            std::mem::swap(&mut self.round, &mut self.next);
        }
        (filled, &self.todo)
    }
}

/// Hole bits from a reconstruction's filter weights: pixels without a point whose weight is
/// zero (no sample reached them). `holes` gets `ceil(width / 64)` words per row.
pub fn holes_from_weights(points: &PointImage, weights: &[f32], holes: &mut Vec<u64>) {
    let w = points.width as usize;
    let words = w.div_ceil(64);
    holes.resize(words * points.height as usize, 0);
    if w == 0 {
        return;
    }
    holes.par_chunks_mut(words).enumerate().for_each(|(y, bits)| {
        for (j, b) in bits.iter_mut().enumerate() {
            let mut word = 0u64;
            for i in 0..(w - 64 * j).min(64) {
                let idx = y * w + 64 * j + i;
                word |= u64::from(weights[idx] == 0.0 && points.point[idx] == NO_POINT) << i;
            }
            *b = word;
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn object_fill_stays_within_objects_and_leaves_unreachable_holes() {
        // Left half object 1 (one red pixel coloured), right half object 2 (one blue pixel);
        // a strip of object 3 with no coloured pixel; everything else a hole.
        let (w, h) = (70usize, 9usize);
        let words = w.div_ceil(64);
        let obj: Vec<u32> = (0..w * h).map(|i| if i / w == 8 { 3 } else if i % w < 35 { 1 } else { 2 }).collect();
        let (red, blue) = (Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 1.0));
        let mut image = vec![Vec3::splat(-1.0); w * h];
        let mut holes = vec![!0u64; words * h];
        for y in 0..h {
            holes[y * words + 1] = (1 << (w - 64)) - 1;
        }
        let mut colour = |x: usize, y: usize, c: Vec3| {
            image[y * w + x] = c;
            holes[y * words + x / 64] &= !(1 << (x % 64));
        };
        colour(3, 2, red);
        colour(60, 6, blue);
        let mut f = ObjectFill::default();
        let (n, left) = f.fill(w, h, &holes, &obj, &mut image);
        assert_eq!(n as usize, 8 * w - 2, "every hole of objects 1 and 2");
        for y in 0..8 {
            for x in 0..w {
                assert_eq!(image[y * w + x], if x < 35 { red } else { blue }, "({x},{y})");
            }
        }
        // The strip of object 3 stays a hole, for the pyramid.
        for x in 0..w {
            assert!(left[8 * words + x / 64] >> (x % 64) & 1 == 1);
            assert_eq!(image[8 * w + x], Vec3::splat(-1.0));
        }
        assert!((0..8).all(|y| left[y * words] == 0 && left[y * words + 1] == 0));
    }

    fn image(w: usize, h: usize, samples: &[(usize, usize, Vec3)]) -> PointImage {
        let n = w * h;
        let mut pi = PointImage {
            width: w as u32,
            height: h as u32,
            point: vec![NO_POINT; n],
            depth: vec![f32::INFINITY; n],
            subpixel: vec![[0.5; 2]; n],
            color: vec![Vec3::ZERO; n],
            age: vec![f32::INFINITY; n],
            born: vec![0; n],
        };
        for &(x, y, c) in samples {
            pi.point[y * w + x] = 0;
            pi.color[y * w + x] = c;
        }
        pi
    }

    #[test]
    fn holes_take_the_nearby_samples_and_the_rest_stays() {
        let (w, h) = (70, 40);
        let red = Vec3::new(1.0, 0.0, 0.0);
        let blue = Vec3::new(0.0, 0.0, 1.0);
        let pi = image(w, h, &[(3, 3, red), (5, 2, red), (60, 36, blue)]);
        let weights: Vec<f32> = (0..w * h).map(|i| if pi.point[i] != NO_POINT { 1.0 } else { 0.0 }).collect();
        let mut holes = Vec::new();
        holes_from_weights(&pi, &weights, &mut holes);
        assert_eq!(holes.len(), 2 * h);
        let mut img = vec![Vec3::splat(-1.0); w * h];
        let mut fill = HoleFill::new(w as u32, h as u32);
        let n = fill.fill(&pi, &holes, &mut img);
        assert_eq!(n as usize, w * h - 3, "every hole has some sample above it");
        // Near the red samples: red; near the blue one: blue; in between a blend.
        assert_eq!(img[4 * w + 4], red);
        assert_eq!(img[38 * w + 62], blue);
        let mid = img[20 * w + 35];
        assert!(mid.x > 0.0 && mid.z > 0.0 && (mid.x + mid.z - 1.0).abs() < 1e-5, "{mid}");
        // Pixels with samples are untouched.
        assert_eq!(img[3 * w + 3], Vec3::splat(-1.0));
        // Without samples nothing is filled.
        let empty = image(w, h, &[]);
        let mut img2 = vec![Vec3::splat(0.5); w * h];
        assert_eq!(fill.fill(&empty, &holes, &mut img2), 0);
        assert!(img2.iter().all(|c| *c == Vec3::splat(0.5)));
        assert!(fill.bytes() < w * h * 2);
    }
}
