//! Geometry exactness: the renderer agrees with the camera model, the
//! ground-truth poses and an independent brute-force plane intersection.

mod common;

use colslam_geometry::{Vec2, Vec3};
use colslam_synth::{Aabb, Distortion, SynthOptions, SyntheticSequence};

const FACES: usize = 6;

/// Every surface as (surface id, box, outward-or-inward face normal sign
/// handled by the caller): room faces first, then 6 per box.
fn surfaces(seq: &SyntheticSequence) -> Vec<(usize, Aabb)> {
    let mut out: Vec<(usize, Aabb)> = (0..FACES).map(|f| (f, *seq.scene().room())).collect();
    for (b, sb) in seq.scene().boxes().iter().enumerate() {
        for f in 0..FACES {
            out.push((FACES * (b + 1) + f, sb.aabb));
        }
    }
    out
}

/// A grid of points on face `f` of `bb` (inset from the edges).
fn face_points(bb: &Aabb, f: usize, n: usize) -> Vec<Vec3> {
    let axis = f / 2;
    let plane = if f.is_multiple_of(2) { bb.min[axis] } else { bb.max[axis] };
    let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut out = Vec::new();
    for a in 0..n {
        for b in 0..n {
            let su = (a as f64 + 0.5) / n as f64;
            let sv = (b as f64 + 0.5) / n as f64;
            let mut p = Vec3::zeros();
            p[axis] = plane;
            p[ua] = bb.min[ua] + su * (bb.max[ua] - bb.min[ua]);
            p[va] = bb.min[va] + sv * (bb.max[va] - bb.min[va]);
            out.push(p);
        }
    }
    out
}

/// Brute-force nearest intersection of `o + t d` with every face plane
/// (checked against the face's rectangle): (t, surface).
fn brute_force(seq: &SyntheticSequence, o: &Vec3, d: &Vec3) -> (f64, usize) {
    let mut best = (f64::INFINITY, usize::MAX);
    for (surface, bb) in surfaces(seq) {
        let f = surface % FACES;
        let axis = f / 2;
        let plane = if f.is_multiple_of(2) { bb.min[axis] } else { bb.max[axis] };
        if d[axis] == 0.0 {
            continue;
        }
        let t = (plane - o[axis]) / d[axis];
        if t <= 0.0 || t >= best.0 {
            continue;
        }
        let p = o + d * t;
        let inside = (0..3).filter(|&k| k != axis).all(|k| p[k] >= bb.min[k] - 1e-12 && p[k] <= bb.max[k] + 1e-12);
        if inside {
            best = (t, surface);
        }
    }
    best
}

fn opts(distortion: Option<Distortion>) -> SynthOptions {
    SynthOptions { distortion, supersample: 1, noise_sigma: 0.0, ..common::small_opts(5, 160, 120) }
}

const DISTORTION: Distortion = [-0.25, 0.08, 0.0015, -0.001];

fn projected_surface_points_match_depth(distortion: Option<Distortion>) {
    let seq = SyntheticSequence::new(&opts(distortion)).unwrap();
    let (w, h) = (seq.options().width as f64, seq.options().height as f64);
    let mut visible = 0;
    let mut occluded = 0;
    for frame in 0..seq.num_frames() {
        for (surface, bb) in surfaces(&seq) {
            for p in face_points(&bb, surface % FACES, 4) {
                let Some((px, depth)) = seq.project(frame, &p).unwrap() else { continue };
                if !(px.x >= 0.0 && px.y >= 0.0 && px.x <= w - 1.0 && px.y <= h - 1.0) {
                    continue;
                }
                let rendered = seq.depth_at(frame, &px).unwrap().expect("inside the image");
                // Never see through a surface; equal when the point is visible.
                assert!(rendered <= depth + 1e-6, "frame {frame} surface {surface}: rendered {rendered} > {depth}");
                if (rendered - depth).abs() <= 1e-6 {
                    visible += 1;
                } else {
                    occluded += 1;
                }
            }
        }
    }
    assert!(visible > 100, "only {visible} visible points ({occluded} occluded)");
    assert!(occluded > 10, "occlusion never happened ({visible} visible)");
}

#[test]
fn surface_points_project_to_their_depth_pinhole() {
    projected_surface_points_match_depth(None);
}

#[test]
fn surface_points_project_to_their_depth_distorted() {
    projected_surface_points_match_depth(Some(DISTORTION));
}

/// Box corners: points 1 mm from each corner on its three faces (the corner
/// itself lies on a silhouette edge, where a ray may graze past) project to
/// pixels whose depth is theirs when visible, and never beyond.
#[test]
fn box_corners_project_exactly() {
    let seq = SyntheticSequence::new(&opts(None)).unwrap();
    let mut matched = 0;
    const INSET: f64 = 1e-3;
    for sb in seq.scene().boxes() {
        let centre = Vec3::from_iterator((0..3).map(|k| 0.5 * (sb.aabb.min[k] + sb.aabb.max[k])));
        for c in sb.aabb.corners() {
            for axis in 0..3 {
                // Stay on the face orthogonal to `axis`: move along the other two.
                let mut p = c;
                for k in (0..3).filter(|&k| k != axis) {
                    p[k] += INSET * (centre[k] - c[k]).signum();
                }
                let Some((px, depth)) = seq.project(0, &p).unwrap() else { continue };
                if !(px.x >= 0.0 && px.y >= 0.0 && px.x <= 159.0 && px.y <= 119.0) {
                    continue;
                }
                let rendered = seq.depth_at(0, &px).unwrap().unwrap();
                assert!(rendered <= depth + 1e-6, "{}: rendered {rendered} > {depth}", sb.name);
                if (rendered - depth).abs() < 1e-6 {
                    matched += 1;
                }
            }
        }
    }
    assert!(matched >= 20, "{matched} visible near-corner points");
}

fn depth_and_colour_match_brute_force(distortion: Option<Distortion>) {
    let seq = SyntheticSequence::new(&opts(distortion)).unwrap();
    let w = seq.options().width;
    let h = seq.options().height;
    for frame in [0, seq.num_frames() - 1] {
        let depth = seq.render_depth(frame).unwrap();
        let img = seq.render(frame).unwrap();
        let pose = seq.world_from_cam()[frame];
        let mut checked = 0;
        for j in (0..h).step_by(5) {
            for i in (0..w).step_by(5) {
                let n = seq.camera().cam_from_img(&Vec2::new(i as f64, j as f64)).unwrap();
                let d = pose.rotation * Vec3::new(n.x, n.y, 1.0);
                let (t, surface) = brute_force(&seq, &pose.translation, &d);
                let r = depth[j * w + i];
                assert!((r - t).abs() <= 1e-9 * t, "frame {frame} pixel ({i}, {j}): depth {r} vs {t}");
                // One sample per pixel, no noise: the pixel is the shaded
                // texture at the intersection (the same surface, unless the
                // ray grazes an edge shared by two surfaces).
                let p = pose.translation + d * t;
                let c = seq.scene().radiance(surface, &p);
                for (k, ck) in c.iter().enumerate() {
                    let expected = ck.round().clamp(0.0, 255.0);
                    let got = img.get(i, j, k) as f32;
                    assert!(
                        (got - expected).abs() <= 1.0,
                        "frame {frame} pixel ({i}, {j}) channel {k}: {got} vs {expected}"
                    );
                }
                checked += 1;
            }
        }
        assert!(checked > 500);
    }
}

#[test]
fn depth_and_colour_match_brute_force_pinhole() {
    depth_and_colour_match_brute_force(None);
}

#[test]
fn depth_and_colour_match_brute_force_distorted() {
    depth_and_colour_match_brute_force(Some(DISTORTION));
}

/// A surface point looks the same in two frames (photo-consistency of poses,
/// camera and renderer): sampled at its projections, the colours agree.
#[test]
fn surface_points_are_photo_consistent_across_frames() {
    let seq = SyntheticSequence::new(&SynthOptions { noise_sigma: 0.0, ..common::small_opts(11, 320, 240) }).unwrap();
    let (w, h) = (320usize, 240usize);
    let (a, b) = (0usize, 2usize);
    let img_a = seq.render(a).unwrap().to_gray();
    let img_b = seq.render(b).unwrap().to_gray();
    let depth = seq.render_depth(a).unwrap();
    let pose_a = seq.world_from_cam()[a];
    let bilinear = |img: &colslam_image::Image, x: f64, y: f64| -> f64 {
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (ax, ay) = (x - x0 as f64, y - y0 as f64);
        let g = |xx: usize, yy: usize| img.get(xx, yy, 0) as f64;
        let top = g(x0, y0) * (1.0 - ax) + g(x0 + 1, y0) * ax;
        let bot = g(x0, y0 + 1) * (1.0 - ax) + g(x0 + 1, y0 + 1) * ax;
        top * (1.0 - ay) + bot * ay
    };
    let mut diffs = Vec::new();
    for j in (4..h - 4).step_by(3) {
        for i in (4..w - 4).step_by(3) {
            let n = seq.camera().cam_from_img(&Vec2::new(i as f64, j as f64)).unwrap();
            let p = pose_a.transform_point(&(Vec3::new(n.x, n.y, 1.0) * depth[j * w + i]));
            let Some((px, z)) = seq.project(b, &p).unwrap() else { continue };
            if px.x < 1.0 || px.y < 1.0 || px.x > (w - 2) as f64 || px.y > (h - 2) as f64 {
                continue;
            }
            // Skip points hidden in frame b.
            let Some(zb) = seq.depth_at(b, &px).unwrap() else { continue };
            if (zb - z).abs() > 1e-6 {
                continue;
            }
            diffs.push((bilinear(&img_b, px.x, px.y) - img_a.get(i, j, 0) as f64).abs());
        }
    }
    assert!(diffs.len() > 3000, "{} points", diffs.len());
    diffs.sort_by(f64::total_cmp);
    let median = diffs[diffs.len() / 2];
    assert!(median < 6.0, "median photometric difference {median}");
    // And a wrong pose gives large differences (the test can fail).
    let mut wrong = Vec::new();
    for j in (4..h - 4).step_by(9) {
        for i in (4..w - 4).step_by(9) {
            wrong.push((img_b.get(i, j, 0) as f64 - img_a.get((i + 7).min(w - 1), j, 0) as f64).abs());
        }
    }
    wrong.sort_by(f64::total_cmp);
    assert!(wrong[wrong.len() / 2] > 2.0 * median, "shifted median {} vs {median}", wrong[wrong.len() / 2]);
}

/// The helpers for estimator tests: visible points reproject exactly, and
/// `observe` finds them again in other frames (or reports occlusion).
#[test]
fn visible_points_and_observations_are_exact() {
    let seq = SyntheticSequence::new(&opts(Some(DISTORTION))).unwrap();
    let pts = seq.visible_points(0, 300, 11).unwrap();
    assert_eq!(pts.len(), 300);
    assert_eq!(pts, seq.visible_points(0, 300, 11).unwrap());
    let mut seen_later = 0;
    for p in &pts {
        let px = seq.observe(0, &p.world).unwrap().expect("visible in its own frame");
        assert!((px - p.pixel).norm() < 1e-6, "reprojection {} px", (px - p.pixel).norm());
        let pc = seq.cam_from_world(0).unwrap().transform_point(&p.world);
        assert!((pc.z - p.depth).abs() < 1e-9);
        if let Some(q) = seq.observe(4, &p.world).unwrap() {
            let (qq, _) = seq.project(4, &p.world).unwrap().unwrap();
            assert_eq!(q, qq);
            seen_later += 1;
        }
    }
    assert!(seen_later > 100 && seen_later < 300, "{seen_later} of 300 seen in frame 4");
}
