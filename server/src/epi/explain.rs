//! A text account of how the EPI saw one pixel and its neighbours: flags, code, region,
//! crossing masks and the point each holds. For diagnosing a reconstruction by hand
//! (`edgepoint-bench quality --explain X,Y`); nothing in the pipeline reads it.
use super::{Epi, Flags};
use crate::render_cache::PointImage;
use glam::Vec3;
use std::fmt::Write;

impl Epi {
    /// The `radius` neighbourhood of pixel (x, y), one line per pixel; `image` is the
    /// reconstruction (row-major, as wide as the EPI) or empty.
    pub fn explain(&self, x: usize, y: usize, radius: usize, points: &PointImage, image: &[Vec3]) -> String {
        let mut s = String::new();
        let (w, h) = (self.width, self.height);
        for yy in y.saturating_sub(radius)..(y + radius + 1).min(h) {
            for xx in x.saturating_sub(radius)..(x + radius + 1).min(w) {
                let i = yy * w + xx;
                let f = |p| if self.flags.get(xx, yy, p) { 1 } else { 0 };
                let px = self.pixels[i];
                let b = &self.bounds;
                let _ = write!(
                    s,
                    "({xx},{yy}) has{} usable{} simple{} complex{} code {:3} region {} primary_b {} sides t{:08b} r{:08b} b{:08b} l{:08b}",
                    f(Flags::HAS),
                    f(Flags::USABLE),
                    f(Flags::SIMPLE),
                    f(Flags::COMPLEX),
                    px.code(),
                    px.region(),
                    px.primary_b(),
                    b.top(xx, yy),
                    b.right(xx, yy),
                    b.bottom(xx, yy),
                    b.left(xx, yy),
                );
                if !b.centres.is_empty() {
                    let _ = write!(s, " centre h{:08b} v{:08b}", b.centre_horizontal(xx, yy), b.centre_vertical(xx, yy));
                }
                if points.point[i] != u32::MAX {
                    let [u, v] = points.subpixel[i];
                    let c = points.color[i];
                    let _ = write!(s, " point ({u:.3},{v:.3}) depth {:.4} colour ({:.3},{:.3},{:.3})", points.depth[i], c.x, c.y, c.z);
                }
                if let Some(c) = image.get(i) {
                    let _ = write!(s, " -> ({:.3},{:.3},{:.3})", c.x, c.y, c.z);
                }
                s.push('\n');
            }
        }
        s
    }
}
