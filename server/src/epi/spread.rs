//! Colour for pixels that reach no sample, without crossing edges (our addition to paper 000
//! §5.3, which leaves such pixels to prioritized sampling). At sparse sampling many pixels'
//! 5 × 5 windows hold no sample reachable from their primary region; filling them with an
//! edge-blind average would blur exactly the edges the EPI exists to keep. Instead colours
//! spread outward from the interpolated pixels, one layer per step (breadth-first): a pixel
//! takes the mean colour of its 4-neighbours that already have one and whose primary region
//! meets its own across their shared side (the neighbour masks' P↔P bit). Complex pixels
//! neither give nor take (their masks are zero). What stays unreached after
//! [`MAX_LAYERS`] layers is left to the edge-blind hole fill
//! ([`crate::render_cache::holes`]).
//!
//! Breadth-first layers make the result independent of scan order: each layer reads only
//! colours of earlier layers.
use super::reach::{Neighbours, NB_PLANES};
use crate::render_cache::holes::{holes_from_weights, HoleFill, ObjectFill};
use crate::render_cache::PointImage;
use glam::Vec3;

/// Layers of spreading at most (pixels farther than this from any interpolated pixel of
/// their region go to the hole fill).
pub const MAX_LAYERS: usize = 16;

/// Reusable buffers.
#[derive(Default)]
pub struct Spread {
    frontier: Vec<u32>,
    next: Vec<u32>,
    /// Bit rows: queued for the next layer.
    queued: Vec<u64>,
}

impl Spread {
    /// Bytes at most, for a `width` × `height` image: both layer queues holding every pixel,
    /// and the queued bit rows.
    pub fn bytes_for(width: usize, height: usize) -> usize {
        2 * 4 * width * height + 8 * height * width.div_ceil(64)
    }

    /// Bytes held (proportional to the pixels spread to in the worst frame).
    pub fn bytes(&self) -> usize {
        4 * (self.frontier.capacity() + self.next.capacity()) + 8 * self.queued.capacity()
    }

    /// Spreads colours into the pixels set in `targets` (bit rows, cleared as they are
    /// filled) from the pixels set in `filled` (set as they are filled), across the shared
    /// sides whose neighbour masks link the two primary regions. Returns the number of
    /// pixels filled.
    pub fn run(&mut self, nb: &Neighbours, filled: &mut [u64], targets: &mut [u64], image: &mut [Vec3]) -> u32 {
        let words = nb.words;
        let pp = |plane: usize, x: usize, y: usize| (nb.planes[(y * NB_PLANES + plane) * words + x / 64] >> (x % 64)) & 1 == 1;
        // Right of (x, y), and below it.
        self.layers(nb.width, nb.height, |x, y| pp(0, x, y), |x, y| pp(4, x, y), filled, targets, image)
    }

    /// The same, ignoring edges: every pair of 4-neighbours is linked (the Render Cache
    /// baseline's hole fill, so that comparisons with it measure the edges).
    pub fn run_unconstrained(&mut self, width: usize, height: usize, filled: &mut [u64], targets: &mut [u64], image: &mut [Vec3]) -> u32 {
        self.layers(width, height, |_, _| true, |_, _| true, filled, targets, image)
    }

    /// Breadth-first layers; `right(x, y)` / `down(x, y)` say whether (x, y) is linked to its
    /// right / lower neighbour.
    #[allow(clippy::too_many_arguments)]
    fn layers(
        &mut self,
        w: usize,
        h: usize,
        right: impl Fn(usize, usize) -> bool,
        down: impl Fn(usize, usize) -> bool,
        filled: &mut [u64],
        targets: &mut [u64],
        image: &mut [Vec3],
    ) -> u32 {
        let words = w.div_ceil(64);
        if w == 0 || h == 0 || targets.iter().all(|&t| t == 0) {
            return 0;
        }
        let bit = |rows: &[u64], x: usize, y: usize| (rows[y * words + x / 64] >> (x % 64)) & 1 == 1;
        // The linked 4-neighbours of (x, y).
        let linked = |x: usize, y: usize, f: &mut dyn FnMut(usize, usize)| {
            if x + 1 < w && right(x, y) {
                f(x + 1, y);
            }
            if x > 0 && right(x - 1, y) {
                f(x - 1, y);
            }
            if y + 1 < h && down(x, y) {
                f(x, y + 1);
            }
            if y > 0 && down(x, y - 1) {
                f(x, y - 1);
            }
        };
        self.queued.clear();
        self.queued.resize(h * words, 0);
        self.frontier.clear();
        for y in 0..h {
            for j in 0..words {
                let mut b = targets[y * words + j];
                while b != 0 {
                    let i = b.trailing_zeros() as usize;
                    b &= b - 1;
                    let x = 64 * j + i;
                    let mut any = false;
                    linked(x, y, &mut |nx, ny| any |= bit(filled, nx, ny));
                    if any {
                        self.frontier.push((y * w + x) as u32);
                        self.queued[y * words + j] |= 1 << i;
                    }
                }
            }
        }
        let mut done = 0u32;
        for _ in 0..MAX_LAYERS {
            if self.frontier.is_empty() {
                break;
            }
            // Colours of this layer from earlier layers only: a pixel of the layer reads only
            // filled neighbours, and the layer is marked filled after all of it is coloured.
            for &p in &self.frontier {
                let (x, y) = (p as usize % w, p as usize / w);
                let (mut sum, mut n) = (Vec3::ZERO, 0u32);
                linked(x, y, &mut |nx, ny| {
                    if bit(filled, nx, ny) {
                        sum += image[ny * w + nx];
                        n += 1;
                    }
                });
                image[p as usize] = sum / n.max(1) as f32;
            }
            self.next.clear();
            for &p in &self.frontier {
                let (x, y) = (p as usize % w, p as usize / w);
                filled[y * words + x / 64] |= 1 << (x % 64);
                targets[y * words + x / 64] &= !(1 << (x % 64));
            }
            done += self.frontier.len() as u32;
            for &p in &self.frontier {
                let (x, y) = (p as usize % w, p as usize / w);
                linked(x, y, &mut |nx, ny| {
                    let (wi, b) = (ny * words + nx / 64, 1u64 << (nx % 64));
                    if targets[wi] & b != 0 && self.queued[wi] & b == 0 {
                        self.queued[wi] |= b;
                        self.next.push((ny * w + nx) as u32);
                    }
                });
            }
            std::mem::swap(&mut self.frontier, &mut self.next);
        }
        done
    }
}

/// Buffers of the Render Cache baseline's hole fill.
#[derive(Default)]
pub struct BaselineHoles {
    spread: Spread,
    holes: Vec<u64>,
    filled: Vec<u64>,
}

impl BaselineHoles {
    /// Bytes at most, for a `width` × `height` image (used once a session switches to the
    /// Render Cache baseline): the spreading queues and two bit planes.
    pub fn bytes_for(width: usize, height: usize) -> usize {
        Spread::bytes_for(width, height) + 2 * 8 * height * width.div_ceil(64)
    }

    /// Fills the pixels of the baseline's frame that no sample reached (no point, weight 0):
    /// within the frame's objects when their per-pixel ids are given (as edge-and-point
    /// reconstruction does), colours spread from neighbouring pixels ignoring edges, then
    /// the pyramid fill for the rest — the same steps as edge-and-point reconstruction minus
    /// the edges. Returns the pixels filled.
    pub fn fill(&mut self, points: &PointImage, weights: &[f32], image: &mut [Vec3], pyramid: &mut HoleFill, objects: Option<(&[u32], &mut ObjectFill)>) -> u32 {
        let (w, h) = (points.width as usize, points.height as usize);
        holes_from_weights(points, weights, &mut self.holes);
        let mut n = 0;
        if let Some((ids, of)) = objects {
            let (k, left) = of.fill(w, h, &self.holes, ids, image);
            n += k;
            self.holes.copy_from_slice(left);
        }
        let words = w.div_ceil(64);
        self.filled.clear();
        self.filled.extend(self.holes.iter().enumerate().map(|(i, &b)| {
            let j = i % words;
            let valid = if 64 * (j + 1) <= w { !0 } else { (1u64 << (w - 64 * j)) - 1 };
            valid & !b
        }));
        n += self.spread.run_unconstrained(w, h, &mut self.filled, &mut self.holes, image);
        n += pyramid.fill(points, &self.holes, image);
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::epi::testutil::{draw_segment, random_points, Fine, Rng};
    use crate::epi::Epi;

    #[test]
    fn colours_spread_within_regions_and_never_across_an_edge() {
        // A vertical edge at x = 10.5 splits a 21 x 9 image; one sample on each side.
        let (w, h) = (21usize, 9usize);
        let mut rng = Rng(1);
        let mut points = random_points(w, h, 0.0, &mut rng);
        let (red, blue) = (Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 1.0));
        for (x, y, c) in [(2usize, 4usize, red), (18, 4, blue)] {
            let i = y * w + x;
            points.point[i] = i as u32;
            points.color[i] = c;
            points.depth[i] = 1.0;
        }
        let mut sides = vec![0u16; (w + 1) * (h + 1)];
        draw_segment(w, h, &mut sides, &mut [], &mut Fine::default(), [10.5, -1.0], [10.5, 10.0]);
        let mut epi = Epi::new(w as u32, h as u32);
        epi.classify_with(sides, Vec::new(), Fine::default(), &points);
        let options = crate::epi::InterpOptions { fallback: false, ..Default::default() };
        let (mut image, mut weights) = (vec![Vec3::ZERO; w * h], vec![0.0; w * h]);
        let mut times = crate::stage_times::StageTimes::new();
        epi.reconstruct(&points, Vec3::splat(0.5), &options, false, &mut image, &mut weights, &mut times);
        // Every pixel left of the edge is red, right of it blue (the edge column mixes by
        // anti-aliasing), and nothing is a hole.
        for y in 0..h {
            for x in 0..w {
                let c = image[y * w + x];
                if x < 10 {
                    assert_eq!(c, red, "({x},{y})");
                } else if x > 10 {
                    assert_eq!(c, blue, "({x},{y})");
                }
            }
        }
        assert!(epi.holes().iter().all(|&b| b == 0));
    }
}
