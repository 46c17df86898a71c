//! Primary visibility: the nearest triangle at every pixel centre, rasterized from the
//! scene's own meshes with the current camera and object transforms (DESIGN.md "Motion";
//! our addition to paper 000 §4.3).
//!
//! The Render Cache (paper 000 §4.3, after Walter et al. 1999) learns what is visible only
//! from its points, and its depth test ("drop points much farther than their neighbours")
//! needs nearer points around a hidden one. In motion that fails where it matters most:
//! when a surface comes into view that has no points yet (the side of a box as the camera
//! orbits), the points of the wall behind it are the only ones there and nothing says they
//! are hidden, so the wall shows through the box; cached background misses likewise land
//! on geometry as black speckles. Rasterizing the triangles' depth answers both exactly and
//! costs little next to shading: every pixel's nearest surface is known, points behind it
//! are culled wherever they reproject, misses never land on geometry, and pixels whose
//! surface has no sample are known to be holes (highest sampling priority, paper §5.3).
//!
//! Rasterization is at pixel centres, inclusive on edges, with every edge function computed
//! from the edge's two endpoints in one canonical order (lexicographic in screen space), so
//! two triangles sharing an edge evaluate it bit for bit alike and no pixel centre falls
//! through a crack between them. Depth is the view depth (along the camera's forward axis,
//! as the Render Cache measures it), from 1/z interpolated linearly in screen space.
//! Triangles crossing the near plane are clipped in view space. Work is split into bands of
//! rows, one rayon task each; the vertices of all objects are transformed once per frame.
//! A frame with the same camera and transforms as the last one reuses the last result.
use edgepoint_scene::camera::CameraFrame;
use edgepoint_scene::Scene;
use glam::{Affine3A, Vec3, Vec3A};
use rayon::prelude::*;

/// Stage name in the frame's stage times.
pub const STAGE_VISIBILITY: &str = "visibility";
/// [`Visibility::object`] of a pixel whose centre no triangle covers.
pub const NO_OBJECT: u32 = u32::MAX;
/// Near clipping distance as a fraction of the scene's bounding-box diagonal.
const NEAR_FRACTION: f32 = 1e-6;
/// Rows per band at least. Bands are the parallel tasks, one per thread: every band looks
/// at every triangle (a quick test of its rows), so more bands cost more than they balance.
const MIN_BAND_ROWS: usize = 8;

/// A vertex in view space and, when in front of the near plane, in screen space.
#[derive(Debug, Clone, Copy, Default)]
struct Vert {
    /// View coordinates: along the camera's right, up and forward axes.
    v: [f32; 3],
    /// Continuous pixel coordinates (valid when `v[2] > near`).
    s: [f32; 2],
}

/// What the last result was drawn for (bitwise, so that reuse is exact).
#[derive(Debug, Clone, PartialEq)]
struct DrawnFor {
    eye: [u32; 3],
    basis: [u32; 9],
    tan_aspect: [u32; 2],
    transforms: Vec<[u32; 12]>,
}

/// The visibility buffer of one image size.
pub struct Visibility {
    width: usize,
    height: usize,
    /// Per pixel: 1/z of the nearest surface at the pixel centre (0 where none): the
    /// nearest surface has the largest 1/z, so no division is needed per pixel, and a
    /// floating-point maximum vectorises on every x86-64.
    invz: Vec<f32>,
    /// Per pixel: the object of that surface, [`NO_OBJECT`] where none.
    obj: Vec<u32>,
    /// Per pixel: the farthest depth over the pixel and its 8 neighbours (`INFINITY` where
    /// any of them is uncovered, or outside the image for none of them).
    far3: Vec<f32>,
    /// Scratch: the 1x3 row minima of 1/z for `far3`'s separable pass.
    rowmin: Vec<f32>,
    /// Scratch: transformed vertices of all objects, and where each object's start.
    verts: Vec<Vert>,
    offsets: Vec<usize>,
    drawn: Option<DrawnFor>,
    /// Draws so far: tells the Render Cache whether what it culls against changed.
    draws: u64,
    /// Triangles drawn (not culled by the object test) and pixels covered in the last draw.
    triangles: u64,
    covered: u32,
}

/// Counts of one [`Visibility::update`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VisibilityCounts {
    /// Whether the buffer was drawn again (false: same camera and transforms as before).
    pub redrawn: bool,
    /// Triangles of the objects inside the view.
    pub triangles: u64,
    /// Pixels whose centre some triangle covers.
    pub covered: u32,
}

impl Visibility {
    pub fn new(width: u32, height: u32) -> Self {
        let (w, h) = (width as usize, height as usize);
        Visibility {
            width: w,
            height: h,
            invz: vec![0.0; w * h],
            obj: vec![NO_OBJECT; w * h],
            far3: vec![f32::INFINITY; w * h],
            rowmin: vec![0.0; w * h],
            verts: Vec::new(),
            offsets: Vec::new(),
            drawn: None,
            draws: 0,
            triangles: 0,
            covered: 0,
        }
    }

    /// Bytes of the image-sized buffers (the vertex scratch grows with the scene).
    pub fn bytes_for(width: u32, height: u32) -> usize {
        width as usize * height as usize * (8 + 4 + 4)
    }

    pub fn width(&self) -> u32 {
        self.width as u32
    }

    pub fn height(&self) -> u32 {
        self.height as u32
    }

    /// Draws the scene's triangles with object `i` at `transforms[i]` as seen by `cam`
    /// (whose size must be this buffer's), unless the last draw was for the same camera and
    /// transforms. Panics if `transforms` does not have one entry per object.
    pub fn update(&mut self, scene: &Scene, transforms: &[Affine3A], cam: &CameraFrame) -> VisibilityCounts {
        assert_eq!(transforms.len(), scene.objects.len(), "one transform per object");
        let key = drawn_for(cam, transforms);
        let redrawn = self.drawn.as_ref() != Some(&key);
        if redrawn {
            self.draw(scene, transforms, cam);
            self.draws += 1;
            self.covered = self.invz.par_iter().with_min_len(16 * 1024).filter(|&&v| v > 0.0).count() as u32;
            self.drawn = Some(key);
        }
        VisibilityCounts { redrawn, triangles: self.triangles, covered: self.covered }
    }

    /// Forgets the last draw, so the next [`Self::update`] draws again.
    pub fn invalidate(&mut self) {
        self.drawn = None;
    }

    /// View depth of the nearest surface at pixel `i` (`INFINITY` where none).
    #[inline]
    pub fn depth(&self, i: usize) -> f32 {
        1.0 / self.invz[i]
    }

    /// Object at pixel `i`, or [`NO_OBJECT`].
    #[inline]
    pub fn object(&self, i: usize) -> u32 {
        self.obj[i]
    }

    /// Per pixel, the object whose surface covers the pixel centre, or [`NO_OBJECT`].
    pub fn objects(&self) -> &[u32] {
        &self.obj
    }

    /// Whether a triangle covers the centre of pixel `i`.
    #[inline]
    pub fn covered(&self, i: usize) -> bool {
        self.invz[i] > 0.0
    }

    /// What the Render Cache's reprojection culls against.
    pub fn cull(&self) -> crate::render_cache::GeometryCull<'_> {
        crate::render_cache::GeometryCull { far3: &self.far3, inverse_depth: &self.invz, generation: self.draws }
    }

    /// Per pixel, the farthest surface depth over its 3x3 neighbourhood (`INFINITY` where
    /// any of those pixel centres is uncovered). A point is certainly hidden when it lies
    /// beyond this depth: every pixel centre around it shows a nearer surface.
    pub fn far3(&self) -> &[f32] {
        &self.far3
    }

    fn draw(&mut self, scene: &Scene, transforms: &[Affine3A], cam: &CameraFrame) {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return;
        }
        let (lo, hi) = scene.bounds();
        let near = ((hi - lo).length() * NEAR_FRACTION).max(1e-6);
        let proj = Proj::new(cam, w, h);

        // Objects inside the view, and their vertices in view and screen space.
        self.offsets.clear();
        let mut total = 0usize;
        let mut visible = Vec::with_capacity(scene.objects.len());
        for (o, t) in scene.objects.iter().zip(transforms) {
            self.offsets.push(total);
            total += o.mesh.positions.len();
            visible.push(proj.object_in_view(o.mesh.bounds, t, near));
        }
        self.verts.resize(total, Vert::default());
        for (i, (o, t)) in scene.objects.iter().zip(transforms).enumerate() {
            if !visible[i] {
                continue;
            }
            let m = proj.view * *t;
            let dst = &mut self.verts[self.offsets[i]..self.offsets[i] + o.mesh.positions.len()];
            let go = |(d, p): (&mut Vert, &Vec3)| *d = proj.vertex(m.transform_point3a(Vec3A::from(*p)), near);
            if dst.len() > 16 * 1024 {
                dst.par_iter_mut().zip(o.mesh.positions.par_iter()).with_min_len(4096).for_each(go);
            } else {
                dst.iter_mut().zip(o.mesh.positions.iter()).for_each(go);
            }
        }
        self.triangles = scene.objects.iter().zip(&visible).filter(|(_, &v)| v).map(|(o, _)| o.mesh.triangles.len() as u64).sum();

        // Bands of rows, each drawing every triangle that reaches it.
        let threads = rayon::current_num_threads().max(1);
        let band_rows = h.div_ceil(threads).max(MIN_BAND_ROWS);
        let (verts, offsets) = (&self.verts, &self.offsets);
        let chunk = band_rows * w;
        self.invz.par_chunks_mut(chunk).zip(self.obj.par_chunks_mut(chunk)).enumerate().for_each(|(b, (invz, obj))| {
            invz.fill(0.0);
            obj.fill(NO_OBJECT);
            let y0 = b * band_rows;
            let y1 = (y0 + band_rows).min(h);
            let mut raster = Band { invz, obj, w, y0, y1, near, proj: &proj };
            for (i, o) in scene.objects.iter().enumerate() {
                if visible[i] {
                    raster.object(&verts[offsets[i]..offsets[i] + o.mesh.positions.len()], &o.mesh.triangles, i as u32);
                }
            }
        });
        self.dilate();
    }

    /// `far3`: the depth of the smallest 1/z over each 3x3 window (separable; an uncovered
    /// pixel's 0 wins, giving infinity).
    fn dilate(&mut self) {
        let w = self.width;
        let h = self.height;
        let invz = &self.invz;
        self.rowmin.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let src = &invz[y * w..(y + 1) * w];
            for (x, m) in row.iter_mut().enumerate() {
                *m = src[x.saturating_sub(1)].min(src[x]).min(src[(x + 1).min(w - 1)]);
            }
        });
        let rm = &self.rowmin;
        self.far3.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            let (a, b, c) = (&rm[y.saturating_sub(1) * w..][..w], &rm[y * w..][..w], &rm[(y + 1).min(h - 1) * w..][..w]);
            for x in 0..w {
                row[x] = 1.0 / a[x].min(b[x]).min(c[x]);
            }
        });
    }
}

fn drawn_for(cam: &CameraFrame, transforms: &[Affine3A]) -> DrawnFor {
    let b = |v: Vec3| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()];
    let (r, u, f) = (b(cam.right), b(cam.up), b(cam.forward));
    DrawnFor {
        eye: b(cam.eye),
        basis: [r[0], r[1], r[2], u[0], u[1], u[2], f[0], f[1], f[2]],
        tan_aspect: [cam.tan_half_y.to_bits(), cam.aspect.to_bits()],
        transforms: transforms
            .iter()
            .map(|t| {
                let c = t.to_cols_array();
                std::array::from_fn(|i| c[i].to_bits())
            })
            .collect(),
    }
}

/// The camera as a world-to-view transform and the view-to-pixel scale, the same
/// projection as the Render Cache's (`render_cache::reproject`).
struct Proj {
    view: Affine3A,
    /// Pixels per unit of x/z and y/z, and the image centre.
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    w: f32,
    h: f32,
}

impl Proj {
    fn new(cam: &CameraFrame, w: usize, h: usize) -> Self {
        let (r, u, f) = (cam.right, cam.up, cam.forward);
        // Rows of the rotation are the camera axes; translation moves the eye to the origin.
        let rot = glam::Mat3::from_cols(Vec3::new(r.x, u.x, f.x), Vec3::new(r.y, u.y, f.y), Vec3::new(r.z, u.z, f.z));
        let view = Affine3A::from_mat3_translation(rot, -(rot * cam.eye));
        let cx = 0.5 * w as f32;
        let cy = 0.5 * h as f32;
        let aspect = w as f32 / h.max(1) as f32;
        Proj { view, fx: cx / (cam.tan_half_y * aspect), fy: cy / cam.tan_half_y, cx, cy, w: w as f32, h: h as f32 }
    }

    #[inline]
    fn vertex(&self, v: Vec3A, near: f32) -> Vert {
        let z = v.z;
        let s = if z > near { [self.cx + v.x * self.fx / z, self.cy - v.y * self.fy / z] } else { [0.0; 2] };
        Vert { v: [v.x, v.y, v.z], s }
    }

    /// Whether any of the object's box can be in view: not wholly behind the near plane,
    /// not wholly beyond one side of the image.
    fn object_in_view(&self, (lo, hi): (Vec3, Vec3), t: &Affine3A, near: f32) -> bool {
        if !(lo.is_finite() && hi.is_finite()) || lo.x > hi.x {
            return false;
        }
        let m = self.view * *t;
        let (mut front, mut behind) = (0, 0);
        let (mut x0, mut x1, mut y0, mut y1) = (f32::INFINITY, f32::NEG_INFINITY, f32::INFINITY, f32::NEG_INFINITY);
        for c in edgepoint_scene::geometry::box_corners((lo, hi)) {
            let v = self.vertex(m.transform_point3a(c.into()), near);
            if v.v[2] > near {
                front += 1;
                x0 = x0.min(v.s[0]);
                x1 = x1.max(v.s[0]);
                y0 = y0.min(v.s[1]);
                y1 = y1.max(v.s[1]);
            } else {
                behind += 1;
            }
        }
        if front == 0 {
            return false;
        }
        // With a corner behind the eye the projected box is unbounded: keep the object.
        behind > 0 || (x1 >= 0.0 && x0 <= self.w && y1 >= 0.0 && y0 <= self.h)
    }
}

/// One band of rows being drawn.
struct Band<'a> {
    invz: &'a mut [f32],
    obj: &'a mut [u32],
    w: usize,
    y0: usize,
    y1: usize,
    near: f32,
    proj: &'a Proj,
}

/// Sub-pixel precision of the snapped vertex coordinates (bits).
const SUB_BITS: u32 = 8;
const SUB: f32 = (1 << SUB_BITS) as f32;
/// Screen coordinates farther than this many pixels outside the image are clipped away in
/// view space first, so that the fixed-point edge functions stay within i64.
const GUARD: f32 = (1 << 20) as f32;

/// A triangle's plane in view space, `n · v = k`, as 1/z over pixel indices:
/// `1/z = gx * x + gy * y + g0` at the centre of pixel (x, y). Taken along the ray through
/// the pixel centre, so it stays exact where projected coordinates are huge (triangles
/// reaching close to the eye).
#[derive(Debug, Clone, Copy)]
struct InvDepth {
    gx: f32,
    gy: f32,
    g0: f32,
}

impl InvDepth {
    /// `None` for a plane through the eye (a triangle seen edge-on covers no pixel centre
    /// reliably).
    fn of(t: &[Vec3; 3], p: &Proj) -> Option<InvDepth> {
        let (a, b, c) = (t[0], t[1], t[2]);
        let n = (b - a).cross(c - a);
        let k = n.dot(a);
        // Also refuses a NaN (every comparison with it is false).
        if k.abs().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || !k.is_finite() {
            return None;
        }
        // Ray direction through pixel centre (x + 0.5, y + 0.5) in view space:
        // ((x + 0.5 - cx) / fx, -(y + 0.5 - cy) / fy, 1); 1/z = n · direction / k.
        let (nx, ny) = (n.x / (p.fx * k), -n.y / (p.fy * k));
        let g0 = n.z / k + nx * (0.5 - p.cx) + ny * (0.5 - p.cy);
        Some(InvDepth { gx: nx, gy: ny, g0 })
    }
}

/// Floor and ceiling of a float as a float, by truncation (the library calls are not
/// inlined without SSE4.1, and these run for every triangle). Exact for |x| < 2^23; larger
/// values are whole numbers already.
#[inline]
fn floor(x: f32) -> f32 {
    // Large, infinite or NaN: already whole, or nothing to round.
    if x.abs().partial_cmp(&8_388_608.0) != Some(std::cmp::Ordering::Less) {
        return x;
    }
    let t = x as i32 as f32;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

#[inline]
fn ceil(x: f32) -> f32 {
    -floor(-x)
}

/// Triangles whose box is at most this many pixels wide are drawn by testing every pixel
/// centre of the box; wider ones by spans.
const NARROW: i64 = 8;

/// Floor and ceiling of a / b for b > 0.
#[inline]
fn floor_div(a: i64, b: i64) -> i64 {
    a.div_euclid(b)
}

#[inline]
fn ceil_div(a: i64, b: i64) -> i64 {
    -((-a).div_euclid(b))
}

impl Band<'_> {
    fn object(&mut self, verts: &[Vert], tris: &[[u32; 3]], object: u32) {
        let (by0, by1) = (self.y0 as f32, self.y1 as f32);
        let near = self.near;
        let (wf, hf) = (self.proj.w, self.proj.h);
        for t in tris {
            let tri = [verts[t[0] as usize], verts[t[1] as usize], verts[t[2] as usize]];
            let [a, b, c] = tri;
            if a.v[2] > near && b.v[2] > near && c.v[2] > near {
                // Pixel-centre rows and columns the triangle's box reaches: most small
                // triangles stop here, in this band or in all.
                let (ymin, ymax) = (a.s[1].min(b.s[1]).min(c.s[1]), a.s[1].max(b.s[1]).max(c.s[1]));
                let (xmin, xmax) = (a.s[0].min(b.s[0]).min(c.s[0]), a.s[0].max(b.s[0]).max(c.s[0]));
                let (ry0, ry1) = (ceil(ymin - 0.5).max(by0), floor(ymax - 0.5).min(by1 - 1.0));
                let (rx0, rx1) = (ceil(xmin - 0.5).max(0.0), floor(xmax - 0.5).min(wf - 1.0));
                if !(ry0 <= ry1 && rx0 <= rx1) {
                    continue;
                }
                if xmin < -GUARD || ymin < -GUARD || xmax > wf + GUARD || ymax > hf + GUARD {
                    self.clipped(tri, object);
                } else if let Some(inv) = InvDepth::of(&tri.map(|v| Vec3::from(v.v)), self.proj) {
                    self.triangle([a.s, b.s, c.s], inv, object);
                }
            } else if a.v[2] > near || b.v[2] > near || c.v[2] > near {
                self.clipped(tri, object);
            }
        }
    }

    /// A triangle reaching behind the near plane or far outside the image: clipped in view
    /// space against the near plane and a guard band around the image, drawn as a fan on
    /// the triangle's own plane.
    fn clipped(&mut self, t: [Vert; 3], object: u32) {
        let p = self.proj;
        let near = self.near;
        let tv = t.map(|v| Vec3::from(v.v));
        let Some(inv) = InvDepth::of(&tv, p) else { return };
        // Planes as f(v) >= 0 inside: z >= near, and -GUARD <= sx <= w + GUARD, the same for sy.
        let planes: [(Vec3, f32); 5] = [
            (Vec3::Z, -near),
            (Vec3::new(p.fx, 0.0, p.cx + GUARD), 0.0),
            (Vec3::new(-p.fx, 0.0, p.w + GUARD - p.cx), 0.0),
            (Vec3::new(0.0, -p.fy, p.cy + GUARD), 0.0),
            (Vec3::new(0.0, p.fy, p.h + GUARD - p.cy), 0.0),
        ];
        let mut poly = [Vec3::ZERO; 9];
        let mut next = [Vec3::ZERO; 9];
        poly[..3].copy_from_slice(&tv);
        let mut n = 3;
        for (pn, pd) in planes {
            let mut m = 0;
            for i in 0..n {
                let (a, b) = (poly[i], poly[(i + 1) % n]);
                let (fa, fb) = (pn.dot(a) + pd, pn.dot(b) + pd);
                if fa >= 0.0 {
                    next[m] = a;
                    m += 1;
                }
                if (fa >= 0.0) != (fb >= 0.0) {
                    next[m] = a + (b - a) * (fa / (fa - fb));
                    m += 1;
                }
            }
            n = m;
            poly[..n].copy_from_slice(&next[..n]);
            if n < 3 {
                return;
            }
        }
        let s: Vec<[f32; 2]> = poly[..n]
            .iter()
            .map(|v| {
                let z = v.z.max(near);
                [p.cx + v.x * p.fx / z, p.cy - v.y * p.fy / z]
            })
            .collect();
        for k in 1..n - 1 {
            self.triangle([s[0], s[k], s[k + 1]], inv, object);
        }
    }

    /// Draws one screen-space triangle into the band: every pixel centre inside it or on its
    /// boundary takes the depth of `inv` there if nearer than what it holds. Vertices are
    /// snapped to 1/256 pixel and the edge functions are exact integers, so two triangles
    /// sharing an edge agree on every pixel centre (inclusive on both: no cracks); each row
    /// is a span found by solving the three edge inequalities.
    fn triangle(&mut self, s: [[f32; 2]; 3], inv: InvDepth, object: u32) {
        let (w, y0, y1) = (self.w as i64, self.y0 as i64, self.y1 as i64);
        // Nearest snapped unit (ties away from zero do not matter: both triangles of an edge
        // snap its endpoints alike).
        let snap = |v: f32| {
            let t = v * SUB;
            (t + if t >= 0.0 { 0.5 } else { -0.5 }) as i64
        };
        let mut p = s.map(|v| (snap(v[0]), snap(v[1])));
        let area = (p[1].0 - p[0].0) * (p[2].1 - p[0].1) - (p[1].1 - p[0].1) * (p[2].0 - p[0].0);
        if area == 0 {
            return;
        }
        if area < 0 {
            p.swap(1, 2);
        }
        // Pixel (x, y) has its centre at ((x + 1/2) SUB, (y + 1/2) SUB) in snapped units.
        let half = 1i64 << (SUB_BITS - 1);
        let one = 1i64 << SUB_BITS;
        let (xmin, xmax) = (p[0].0.min(p[1].0).min(p[2].0), p[0].0.max(p[1].0).max(p[2].0));
        let (ymin, ymax) = (p[0].1.min(p[1].1).min(p[2].1), p[0].1.max(p[1].1).max(p[2].1));
        let ix0 = ceil_div(xmin - half, one).max(0);
        let ix1 = floor_div(xmax - half, one).min(w - 1);
        let iy0 = ceil_div(ymin - half, one).max(y0);
        let iy1 = floor_div(ymax - half, one).min(y1 - 1);
        if ix0 > ix1 || iy0 > iy1 {
            return;
        }
        // Edge a→b: E(x, y) = (bx - ax)(Py - ay) - (by - ay)(Px - ax) = A x + B y + C in
        // pixel indices; inside when all three are >= 0.
        let edge = |a: (i64, i64), b: (i64, i64)| {
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            (-dy * one, dx * one, dx * (half - a.1) - dy * (half - a.0))
        };
        let edges = [edge(p[0], p[1]), edge(p[1], p[2]), edge(p[2], p[0])];
        let w_us = self.w;
        let narrow = ix1 - ix0 < NARROW;
        for y in iy0..=iy1 {
            let row0 = (y - y0) as usize * w_us;
            let base = inv.gy * y as f32 + inv.g0;
            if narrow {
                // Small triangles (most of a big mesh): test each centre of the box's row
                // with the edge values stepped exactly in integers.
                let mut e = edges.map(|(a, b, c)| a * ix0 + b * y + c);
                for x in ix0..=ix1 {
                    if e[0] >= 0 && e[1] >= 0 && e[2] >= 0 {
                        let i = row0 + x as usize;
                        let v = base + inv.gx * x as f32;
                        if v > self.invz[i] && v < f32::INFINITY {
                            self.invz[i] = v;
                            self.obj[i] = object;
                        }
                    }
                    for k in 0..3 {
                        e[k] += edges[k].0;
                    }
                }
                continue;
            }
            // Wide triangles: the row's span from the three edge inequalities, each bound
            // estimated in f64 and made exact with the integer edge function.
            let (mut xs, mut xe) = (ix0, ix1);
            for &(a, b, c) in &edges {
                let r = b * y + c;
                let at = |x: i64| a * x + r;
                if a > 0 {
                    let mut x = (-(r as f64) / a as f64).ceil() as i64;
                    while at(x) < 0 {
                        x += 1;
                    }
                    while at(x - 1) >= 0 {
                        x -= 1;
                    }
                    xs = xs.max(x);
                } else if a < 0 {
                    let mut x = (r as f64 / -(a as f64)).floor() as i64;
                    while at(x) < 0 {
                        x -= 1;
                    }
                    while at(x + 1) >= 0 {
                        x += 1;
                    }
                    xe = xe.min(x);
                } else if r < 0 {
                    xe = -1;
                }
            }
            if xs > xe {
                continue;
            }
            let span = row0 + xs as usize..=row0 + xe as usize;
            let x0 = xs as f32;
            for (k, (iz, ob)) in self.invz[span.clone()].iter_mut().zip(&mut self.obj[span]).enumerate() {
                // A 1/z that is not positive and finite never wins (NaN compares false).
                // Branch-free, so the loop vectorises.
                let v = base + inv.gx * (x0 + k as f32);
                let win = v > *iz && v < f32::INFINITY;
                *iz = if win { v } else { *iz };
                *ob = if win { object } else { *ob };
            }
        }
    }
}

#[cfg(test)]
mod tests;
