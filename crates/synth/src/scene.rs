//! The synthetic room: an inside-out box with furniture-like axis-aligned
//! boxes, every face with its own baked texture, and exact ray casting.
//!
//! World frame: x along the room length, y along its width, z up; the floor
//! is `z = 0` and the room is centred on the z axis.

use colslam_geometry::{SplitMix64, Vec3};
use rayon::prelude::*;
use serde::Serialize;

use crate::options::SynthOptions;
use crate::texture::Texture;

/// Ambient light share.
const AMBIENT: f32 = 0.35;
/// Directional lights: (direction towards the light, intensity).
const LIGHTS: [([f64; 3], f32); 2] = [([0.3, 0.2, 1.0], 0.55), ([-0.6, 0.7, 0.3], 0.3)];
/// Faces per box.
pub const FACES_PER_BOX: usize = 6;
/// Smallest clearance in metres between the camera path and any box or wall.
pub const CAMERA_CLEARANCE: f64 = 0.15;
/// Tries to place one clutter box before giving up on it.
const CLUTTER_TRIES: usize = 30;

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Aabb {
    /// Minimum corner.
    pub min: [f64; 3],
    /// Maximum corner.
    pub max: [f64; 3],
}

impl Aabb {
    fn new(min: [f64; 3], max: [f64; 3]) -> Self {
        Self { min, max }
    }

    /// The 8 corners.
    pub fn corners(&self) -> [Vec3; 8] {
        let mut out = [Vec3::zeros(); 8];
        for (k, c) in out.iter_mut().enumerate() {
            *c = Vec3::new(
                if k & 1 == 0 { self.min[0] } else { self.max[0] },
                if k & 2 == 0 { self.min[1] } else { self.max[1] },
                if k & 4 == 0 { self.min[2] } else { self.max[2] },
            );
        }
        out
    }

    /// Edge lengths.
    pub fn size(&self) -> [f64; 3] {
        [self.max[0] - self.min[0], self.max[1] - self.min[1], self.max[2] - self.min[2]]
    }

    /// True when the boxes overlap after growing `self` by `margin`.
    fn overlaps(&self, o: &Aabb, margin: f64) -> bool {
        (0..3).all(|k| self.min[k] - margin < o.max[k] && o.min[k] < self.max[k] + margin)
    }

    /// Distance from a point to the box (0 inside).
    pub fn distance(&self, p: &Vec3) -> f64 {
        let mut d2 = 0.0;
        for k in 0..3 {
            let e = (self.min[k] - p[k]).max(p[k] - self.max[k]).max(0.0);
            d2 += e * e;
        }
        d2.sqrt()
    }
}

/// A furniture box of the scene.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SceneBox {
    /// What it stands for (e.g. "table top", "shelf board").
    pub name: String,
    /// Its extent.
    pub aabb: Aabb,
}

/// Where a ray hit the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Ray parameter: with a direction of camera-z component 1 this is the
    /// depth of the hit in the camera.
    pub t: f64,
    /// Surface id: `0..6` the room faces, `6 + 6 * b + f` face `f` of box `b`.
    /// Face `f = 2 * axis + side` (side 0 = the face at `min[axis]`).
    pub surface: usize,
}

/// The whole scene: room, boxes, per-face textures and shading.
#[derive(Clone)]
pub struct Scene {
    room: Aabb,
    boxes: Vec<SceneBox>,
    /// One texture per surface (room faces first, then 6 per box).
    textures: Vec<Texture>,
    /// Lambert + ambient factor per surface.
    shade: Vec<f32>,
}

impl std::fmt::Debug for Scene {
    /// A summary (the textures are megabytes).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("room", &self.room)
            .field("boxes", &self.boxes.len())
            .field("surfaces", &self.textures.len())
            .field("texels", &self.texels())
            .finish()
    }
}

/// The `(u, v)` axes of a face orthogonal to `axis`.
#[inline]
fn face_axes(axis: usize) -> (usize, usize) {
    ((axis + 1) % 3, (axis + 2) % 3)
}

/// Outward normal of face `f` of a box.
fn box_face_normal(f: usize) -> Vec3 {
    let mut n = Vec3::zeros();
    n[f / 2] = if f.is_multiple_of(2) { -1.0 } else { 1.0 };
    n
}

fn shade_for(normal: &Vec3) -> f32 {
    let mut s = AMBIENT;
    for (dir, intensity) in LIGHTS {
        let l = Vec3::new(dir[0], dir[1], dir[2]).normalize();
        s += intensity * normal.dot(&l).max(0.0) as f32;
    }
    s
}

/// Slab test (Kay & Kajiya 1986) of a ray from the origin with direction
/// reciprocals `inv` against the box `[lo, hi]` given relative to the ray
/// origin: the entry parameter (> 0) and the entry face `2 * axis + side`.
#[inline]
pub(crate) fn slab(lo: &[f64; 3], hi: &[f64; 3], inv: &[f64; 3]) -> Option<(f64, usize)> {
    let mut tmin = f64::NEG_INFINITY;
    let mut tmax = f64::INFINITY;
    let mut face = 0;
    for k in 0..3 {
        let t1 = lo[k] * inv[k];
        let t2 = hi[k] * inv[k];
        let (near, far, f) = if t1 <= t2 { (t1, t2, 2 * k) } else { (t2, t1, 2 * k + 1) };
        // NaN (ray in the slab's plane) fails both comparisons and is
        // ignored, which treats it as inside that slab.
        if near > tmin {
            tmin = near;
            face = f;
        }
        if far < tmax {
            tmax = far;
        }
    }
    (tmin <= tmax && tmin > 0.0).then_some((tmin, face))
}

/// Places boxes into a layout, with the seeded jitter.
struct Layout {
    rng: SplitMix64,
    boxes: Vec<SceneBox>,
}

impl Layout {
    fn jit(&mut self, amount: f64) -> f64 {
        self.rng.uniform(-amount, amount)
    }
    fn add(&mut self, name: &str, min: [f64; 3], max: [f64; 3]) {
        self.boxes.push(SceneBox { name: name.to_string(), aabb: Aabb::new(min, max) });
    }
    /// A box with footprint centre `(cx, cy)`, size `(sx, sy, sz)`, standing on `z0`.
    fn add_on(&mut self, name: &str, cx: f64, cy: f64, z0: f64, s: [f64; 3]) -> f64 {
        self.add(name, [cx - s[0] / 2.0, cy - s[1] / 2.0, z0], [cx + s[0] / 2.0, cy + s[1] / 2.0, z0 + s[2]]);
        z0 + s[2]
    }
}

impl Scene {
    /// Builds the room and its furniture (jittered by the seed) and bakes the
    /// textures (in parallel).
    pub fn build(opts: &SynthOptions) -> Scene {
        let [rx, ry, rz] = opts.room_size;
        let (hx, hy) = (rx / 2.0, ry / 2.0);
        let room = Aabb::new([-hx, -hy, 0.0], [hx, hy, rz]);
        let mut l = Layout { rng: SplitMix64::new(opts.seed ^ 0x5CE4_E000_0000_0001), boxes: Vec::new() };

        // Central table with legs and stacked boxes on it.
        let (tx, ty) = (l.jit(0.1), l.jit(0.1));
        let (tsx, tsy) = (1.4 + l.jit(0.1), 0.9 + l.jit(0.05));
        let (top, thick, leg) = (0.75, 0.04, 0.05);
        l.add("table top", [tx - tsx / 2.0, ty - tsy / 2.0, top - thick], [tx + tsx / 2.0, ty + tsy / 2.0, top]);
        for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            let cx = tx + sx * (tsx / 2.0 - leg);
            let cy = ty + sy * (tsy / 2.0 - leg);
            l.add_on("table leg", cx, cy, 0.0, [leg, leg, top - thick]);
        }
        let (ax, ay) = (tx - 0.35 + l.jit(0.05), ty + 0.1 + l.jit(0.05));
        let za = l.add_on("box", ax, ay, top, [0.36, 0.26, 0.2]);
        let zb = l.add_on("stacked box", ax + 0.03, ay - 0.02, za, [0.24, 0.18, 0.14]);
        l.add_on("stacked box", ax + 0.02, ay - 0.01, zb, [0.12, 0.1, 0.07]);
        let (cx, cy) = (tx + 0.35 + l.jit(0.05), ty - 0.18 + l.jit(0.03));
        let zc = l.add_on("box", cx, cy, top, [0.3, 0.26, 0.12]);
        l.add_on("stacked box", cx - 0.05, cy + 0.03, zc, [0.12, 0.12, 0.08]);
        let bx = tx + 0.1 + l.jit(0.03);
        l.add_on("book block", bx, ty + 0.25, top, [0.1, 0.24, 0.3]);

        // Shelf against the +x wall: two sides, boards, a back panel, items.
        let (sy0, sw, sd, sh, bt) = (l.jit(0.4), 1.2, 0.35, 1.8, 0.03);
        let x0 = hx - sd;
        l.add("shelf back", [hx - 0.02, sy0 - sw / 2.0 + bt, 0.0], [hx, sy0 + sw / 2.0 - bt, sh]);
        l.add("shelf side", [x0, sy0 - sw / 2.0, 0.0], [hx, sy0 - sw / 2.0 + bt, sh]);
        l.add("shelf side", [x0, sy0 + sw / 2.0 - bt, 0.0], [hx, sy0 + sw / 2.0, sh]);
        for k in 0..5 {
            let z = k as f64 * (sh - bt) / 4.0;
            l.add("shelf board", [x0, sy0 - sw / 2.0 + bt, z], [hx - 0.02, sy0 + sw / 2.0 - bt, z + bt]);
            if k < 4 {
                // Two or three items per shelf level.
                let mut y = sy0 - sw / 2.0 + bt + 0.03;
                let items = 2 + l.rng.below(2);
                for _ in 0..items {
                    let w = l.rng.uniform(0.12, 0.3);
                    let h = l.rng.uniform(0.12, 0.35);
                    let d = l.rng.uniform(0.15, 0.28);
                    if y + w > sy0 + sw / 2.0 - bt - 0.02 {
                        break;
                    }
                    l.add("shelf item", [hx - 0.02 - d, y, z + bt], [hx - 0.02, y + w, z + bt + h]);
                    y += w + l.rng.uniform(0.04, 0.12);
                }
            }
        }

        // Cabinet against the -y wall with a box on top.
        let c0 = -1.3 + l.jit(0.2);
        let ztop = l.add_on("cabinet", c0 + 0.4, -hy + 0.25, 0.0, [0.8, 0.5, 0.9]);
        l.add_on("box", c0 + 0.3, -hy + 0.22, ztop, [0.3, 0.3, 0.25]);
        // Sideboard against the +y wall with two boxes.
        let s0 = 0.6 + l.jit(0.2);
        let ztop = l.add_on("sideboard", s0, hy - 0.225, 0.0, [1.6, 0.45, 0.7]);
        l.add_on("box", s0 - 0.45, hy - 0.2, ztop, [0.35, 0.25, 0.3]);
        l.add_on("box", s0 + 0.4, hy - 0.25, ztop, [0.25, 0.3, 0.18]);
        // Tall cabinet against the -x wall.
        let t0 = -0.4 + l.jit(0.3);
        l.add_on("tall cabinet", -hx + 0.275, t0, 0.0, [0.55, 0.8, 2.0]);

        // Clutter: random boxes on the floor along the walls, sometimes stacked.
        for _ in 0..opts.clutter_boxes {
            for _ in 0..CLUTTER_TRIES {
                let s = [l.rng.uniform(0.2, 0.5), l.rng.uniform(0.2, 0.5), l.rng.uniform(0.15, 0.6)];
                let wall = l.rng.below(4);
                let along = l.rng.uniform(-1.0, 1.0);
                let off = l.rng.uniform(0.02, 0.15);
                let (cx, cy) = match wall {
                    0 => (hx - off - s[0] / 2.0, along * (hy - 0.4)),
                    1 => (-hx + off + s[0] / 2.0, along * (hy - 0.4)),
                    2 => (along * (hx - 0.4), hy - off - s[1] / 2.0),
                    _ => (along * (hx - 0.4), -hy + off + s[1] / 2.0),
                };
                let cand = Aabb::new([cx - s[0] / 2.0, cy - s[1] / 2.0, 0.0], [cx + s[0] / 2.0, cy + s[1] / 2.0, s[2]]);
                if l.boxes.iter().any(|b| b.aabb.overlaps(&cand, 0.02)) {
                    continue;
                }
                l.add("clutter box", cand.min, cand.max);
                if l.rng.below(2) == 0 {
                    let t = [s[0] * l.rng.uniform(0.5, 0.9), s[1] * l.rng.uniform(0.5, 0.9), l.rng.uniform(0.1, 0.3)];
                    l.add_on("stacked box", cx, cy, s[2], t);
                }
                break;
            }
        }
        let boxes = l.boxes;

        // One texture per surface: (width_m, height_m, normal).
        let mut specs: Vec<(f64, f64, Vec3)> = Vec::with_capacity(FACES_PER_BOX * (boxes.len() + 1));
        for f in 0..FACES_PER_BOX {
            let (ua, va) = face_axes(f / 2);
            let s = room.size();
            specs.push((s[ua], s[va], -box_face_normal(f)));
        }
        for b in &boxes {
            for f in 0..FACES_PER_BOX {
                let (ua, va) = face_axes(f / 2);
                let s = b.aabb.size();
                specs.push((s[ua], s[va], box_face_normal(f)));
            }
        }
        let tex_seed = opts.seed ^ 0x7E47_0000_0000_0002;
        let texel = opts.texel_size;
        let textures: Vec<Texture> = specs
            .par_iter()
            .enumerate()
            .map(|(k, (w, h, _))| {
                let seed = SplitMix64::new(tex_seed.wrapping_add(k as u64)).next_u64();
                Texture::bake(*w, *h, texel, seed)
            })
            .collect();
        let shade = specs.iter().map(|(_, _, n)| shade_for(n)).collect();
        Scene { room, boxes, textures, shade }
    }

    /// The room (the scene's bounding box).
    pub fn room(&self) -> &Aabb {
        &self.room
    }

    /// The furniture boxes.
    pub fn boxes(&self) -> &[SceneBox] {
        &self.boxes
    }

    /// Number of surfaces (6 room faces + 6 per box).
    pub fn num_surfaces(&self) -> usize {
        self.textures.len()
    }

    /// Total texels over all textures.
    pub fn texels(&self) -> usize {
        self.textures.iter().map(Texture::texels).sum()
    }

    /// Distance from a point to the nearest box or wall (negative outside the room).
    pub fn clearance(&self, p: &Vec3) -> f64 {
        let mut d = f64::INFINITY;
        for k in 0..3 {
            d = d.min(p[k] - self.room.min[k]).min(self.room.max[k] - p[k]);
        }
        for b in &self.boxes {
            d = d.min(b.aabb.distance(p));
        }
        d
    }

    /// Where a ray `o + t d` (`t > 0`) from inside the room leaves it;
    /// `inv` holds the reciprocals of `d`'s components.
    #[inline]
    pub(crate) fn room_exit(&self, o: &Vec3, d: &Vec3, inv: &[f64; 3]) -> Hit {
        let mut best = Hit { t: f64::INFINITY, surface: 0 };
        for k in 0..3 {
            let (t, side) = if d[k] > 0.0 {
                ((self.room.max[k] - o[k]) * inv[k], 1)
            } else if d[k] < 0.0 {
                ((self.room.min[k] - o[k]) * inv[k], 0)
            } else {
                continue;
            };
            if t < best.t {
                best = Hit { t, surface: 2 * k + side };
            }
        }
        best
    }

    /// Casts a ray `o + t d` (`t > 0`) from inside the room, testing the
    /// boxes listed in `candidates` (indices into [`Scene::boxes`]) and the room.
    pub fn cast_candidates(&self, o: &Vec3, d: &Vec3, candidates: impl IntoIterator<Item = usize>) -> Hit {
        let inv = [1.0 / d.x, 1.0 / d.y, 1.0 / d.z];
        let mut best = self.room_exit(o, d, &inv);
        for b in candidates {
            let Some(sb) = self.boxes.get(b) else { continue };
            let bb = &sb.aabb;
            let lo = [bb.min[0] - o[0], bb.min[1] - o[1], bb.min[2] - o[2]];
            let hi = [bb.max[0] - o[0], bb.max[1] - o[1], bb.max[2] - o[2]];
            if let Some((t, face)) = slab(&lo, &hi, &inv)
                && t < best.t
            {
                best = Hit { t, surface: FACES_PER_BOX * (b + 1) + face };
            }
        }
        best
    }

    /// Casts a ray against every box and the room.
    pub fn cast(&self, o: &Vec3, d: &Vec3) -> Hit {
        self.cast_candidates(o, d, 0..self.boxes.len())
    }

    /// The box (or the room for surfaces 0..6) of a surface, and its face.
    fn surface_box(&self, surface: usize) -> Option<(&Aabb, usize)> {
        let face = surface % FACES_PER_BOX;
        if surface < FACES_PER_BOX {
            Some((&self.room, face))
        } else {
            self.boxes.get(surface / FACES_PER_BOX - 1).map(|b| (&b.aabb, face))
        }
    }

    /// Surface texture coordinates (metres) of a point on a surface.
    #[inline]
    fn surface_uv(bb: &Aabb, face: usize, p: &Vec3) -> (f64, f64) {
        let (ua, va) = face_axes(face / 2);
        (p[ua] - bb.min[ua], p[va] - bb.min[va])
    }

    /// The albedo (texture colour, 0..255) of `surface` at the point `p` on it.
    #[inline]
    pub fn albedo(&self, surface: usize, p: &Vec3) -> [f32; 3] {
        match (self.surface_box(surface), self.textures.get(surface)) {
            (Some((bb, face)), Some(tex)) => {
                let (u, v) = Self::surface_uv(bb, face, p);
                tex.sample(u, v)
            }
            _ => [0.0; 3],
        }
    }

    /// The shaded colour (0..255, may exceed 255 before clamping) of
    /// `surface` at `p`: albedo times (ambient + Lambert).
    #[inline]
    pub fn radiance(&self, surface: usize, p: &Vec3) -> [f32; 3] {
        let a = self.albedo(surface, p);
        let s = self.shade.get(surface).copied().unwrap_or(AMBIENT);
        [a[0] * s, a[1] * s, a[2] * s]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> Scene {
        Scene::build(&SynthOptions { texel_size: 0.05, ..Default::default() })
    }

    #[test]
    fn boxes_inside_room_and_disjoint() {
        let s = small();
        assert!(s.boxes().len() >= 20, "{} boxes", s.boxes().len());
        for (i, a) in s.boxes().iter().enumerate() {
            for k in 0..3 {
                assert!(
                    a.aabb.min[k] >= s.room().min[k] - 1e-12 && a.aabb.max[k] <= s.room().max[k] + 1e-12,
                    "{}",
                    a.name
                );
                assert!(a.aabb.min[k] < a.aabb.max[k]);
            }
            for b in &s.boxes()[i + 1..] {
                // Touching faces (stacking) are allowed, interpenetration is not.
                assert!(!a.aabb.overlaps(&b.aabb, -1e-9), "{} overlaps {}", a.name, b.name);
            }
        }
    }

    #[test]
    fn cast_hits_box_faces_exactly() {
        let s = small();
        let o = Vec3::new(0.0, -2.0, 1.4);
        // Aim at the centre of the top face of the table top.
        let table = s.boxes()[0].aabb;
        let target =
            Vec3::new(0.5 * (table.min[0] + table.max[0]), 0.5 * (table.min[1] + table.max[1]) - 0.3, table.max[2]);
        let d = target - o;
        let hit = s.cast(&o, &d);
        assert!((hit.t - 1.0).abs() < 1e-12, "t = {}", hit.t);
        assert_eq!(hit.surface, FACES_PER_BOX + 5);
        // Straight up hits the ceiling.
        let up = s.cast(&o, &Vec3::new(0.0, 0.0, 2.0));
        assert_eq!(up.surface, 5);
        assert!((up.t * 2.0 - (s.room().max[2] - 1.4)).abs() < 1e-12);
    }
}
