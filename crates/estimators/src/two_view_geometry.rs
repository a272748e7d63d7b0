//! Two-view geometry as COLMAP estimates it (`estimators/two_view_geometry.cc`,
//! `EstimateCalibratedTwoViewGeometry`): fit E, F and H with RANSAC, classify
//! the pair from their inlier counts, then recover the relative pose and the
//! median triangulation angle. Pure rotation (panoramic) is detected when the
//! homography explains the matches and the triangulation angles are tiny.

use crate::error::{EstimatorError, check_pairs};
use crate::essential_5pt::{RecoveredPose, pose_from_essential};
use crate::homography::pose_from_homography;
use crate::ransac::{RansacOptions, RansacReport};
use crate::relative_pose::{estimate_essential, estimate_fundamental, estimate_homography};
use crate::triangulation::triangulation_angle;
use crate::{Mat3, Vec2, Vec3};
use colslam_geometry::Rigid3;
use colslam_geometry::stats::upper_median_in_place;

/// Classification of an image pair (COLMAP's `TwoViewGeometry::ConfigurationType`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TwoViewConfig {
    /// Not enough consistent matches for any model.
    Degenerate,
    /// The essential matrix explains the matches (general 3D scene).
    Calibrated,
    /// Only a fundamental matrix explains the matches (calibration suspect).
    Uncalibrated,
    /// A homography explains most matches and the camera translated: planar scene.
    Planar,
    /// A homography explains most matches; no pose could separate planar from panoramic.
    PlanarOrPanoramic,
    /// Pure rotation (or a baseline negligible relative to depth).
    Panoramic,
}

/// Options of [`estimate_two_view_geometry`]. Thresholds are in normalised
/// units (pixels divided by the focal length).
#[derive(Debug, Clone, PartialEq)]
pub struct TwoViewGeometryOptions {
    /// RANSAC options for E, F and H (its `max_error` is the inlier
    /// threshold of all three). Default: max_error 8e-3 (4 px at 500 px, as
    /// COLMAP's 4 px), confidence 0.999, at most 10 000 trials.
    pub ransac: RansacOptions,
    /// Minimum inliers for a model to count. Default 15 (COLMAP).
    pub min_num_inliers: usize,
    /// E is accepted when `inliers(E) / inliers(F)` exceeds this. Default 0.95 (COLMAP).
    pub min_e_f_inlier_ratio: f64,
    /// The pair is planar or panoramic when `inliers(H) / inliers(E or F)`
    /// exceeds this. Default 0.8 (COLMAP).
    pub max_h_inlier_ratio: f64,
    /// A planar-or-panoramic pair whose median triangulation angle is below
    /// this (degrees) is classified Panoramic. Default 0.5.
    pub max_panoramic_tri_angle_deg: f64,
}

impl Default for TwoViewGeometryOptions {
    fn default() -> Self {
        Self {
            ransac: RansacOptions {
                max_error: 8e-3,
                confidence: 0.999,
                max_trials: 10_000,
                ..RansacOptions::default()
            },
            min_num_inliers: 15,
            min_e_f_inlier_ratio: 0.95,
            max_h_inlier_ratio: 0.8,
            max_panoramic_tri_angle_deg: 0.5,
        }
    }
}

impl TwoViewGeometryOptions {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), EstimatorError> {
        self.ransac.validate()?;
        let bad = |m: String| Err(EstimatorError::InvalidOptions(m));
        if self.min_num_inliers < 5 {
            return bad(format!("two-view min_num_inliers must be >= 5, got {}", self.min_num_inliers));
        }
        if !(self.min_e_f_inlier_ratio > 0.0 && self.max_h_inlier_ratio > 0.0) {
            return bad("two-view inlier ratios must be positive".into());
        }
        if !(self.max_panoramic_tri_angle_deg >= 0.0) {
            return bad("max_panoramic_tri_angle_deg must be non-negative".into());
        }
        Ok(())
    }
}

/// Result of [`estimate_two_view_geometry`].
#[derive(Debug, Clone)]
pub struct TwoViewGeometry {
    /// The classification.
    pub config: TwoViewConfig,
    /// Essential matrix, when RANSAC found one.
    pub essential: Option<Mat3>,
    /// Fundamental matrix, when RANSAC found one.
    pub fundamental: Option<Mat3>,
    /// Homography, when RANSAC found one.
    pub homography: Option<Mat3>,
    /// Inliers of E, F and H (0 when not found).
    pub num_inliers_e: usize,
    /// See `num_inliers_e`.
    pub num_inliers_f: usize,
    /// See `num_inliers_e`.
    pub num_inliers_h: usize,
    /// Inlier matches of the model that defines `config`.
    pub inlier_mask: Vec<bool>,
    /// Number of inlier matches.
    pub num_inliers: usize,
    /// `cam2_from_cam1` (unit translation; zero for Panoramic); `None` for
    /// Degenerate and Uncalibrated pairs.
    pub cam2_from_cam1: Option<Rigid3>,
    /// Median triangulation angle (degrees) of the inliers that triangulate
    /// in front of both cameras; `None` when there is no pose.
    pub median_tri_angle_deg: Option<f64>,
}

/// Median triangulation angle (degrees) of a recovered pose's points in
/// front of both cameras; `None` when there is none.
pub fn median_tri_angle_deg(pose: &RecoveredPose) -> Option<f64> {
    let c2 = pose.cam2_from_cam1.center();
    let mut angles: Vec<f64> = pose
        .points3d
        .iter()
        .zip(&pose.valid)
        .filter(|(_, v)| **v)
        .map(|(p, _)| triangulation_angle(&Vec3::zeros(), &c2, p).to_degrees())
        .collect();
    // The upper median: one of the angles, never an average of two.
    upper_median_in_place(&mut angles)
}

fn masked(x: &[Vec2], mask: &[bool]) -> Vec<Vec2> {
    x.iter().zip(mask).filter(|(_, m)| **m).map(|(p, _)| *p).collect()
}

/// Estimates and classifies the geometry of an image pair from putative
/// matches in normalised coordinates. Bad input (NaN, length mismatch,
/// invalid options) is an error; too few or inconsistent matches give
/// `config == Degenerate`.
pub fn estimate_two_view_geometry(
    x1: &[Vec2],
    x2: &[Vec2],
    opts: &TwoViewGeometryOptions,
) -> Result<TwoViewGeometry, EstimatorError> {
    opts.validate()?;
    check_pairs("two-view geometry", x1, x2, 0)?;
    let n = x1.len();
    let mut out = TwoViewGeometry {
        config: TwoViewConfig::Degenerate,
        essential: None,
        fundamental: None,
        homography: None,
        num_inliers_e: 0,
        num_inliers_f: 0,
        num_inliers_h: 0,
        inlier_mask: vec![false; n],
        num_inliers: 0,
        cam2_from_cam1: None,
        median_tri_angle_deg: None,
    };
    if n < opts.min_num_inliers {
        return Ok(out);
    }
    let e = estimate_essential(x1, x2, &opts.ransac).ok();
    let f = estimate_fundamental(x1, x2, &opts.ransac).ok();
    let h = estimate_homography(x1, x2, &opts.ransac).ok();
    let count = |r: &Option<RansacReport<Mat3>>| r.as_ref().map_or(0, |r| r.num_inliers);
    let (ne, nf, nh) = (count(&e), count(&f), count(&h));
    out.essential = e.as_ref().map(|r| r.model);
    out.fundamental = f.as_ref().map(|r| r.model);
    out.homography = h.as_ref().map(|r| r.model);
    (out.num_inliers_e, out.num_inliers_f, out.num_inliers_h) = (ne, nf, nh);
    let min = opts.min_num_inliers;
    let ratio = |a: usize, b: usize| if b > 0 { a as f64 / b as f64 } else { f64::INFINITY };

    // Classification (COLMAP's order of tests).
    let (config, mask) = if let Some(er) = e.as_ref().filter(|_| ne >= min && ratio(ne, nf) > opts.min_e_f_inlier_ratio)
    {
        if ratio(nh, ne) > opts.max_h_inlier_ratio {
            (TwoViewConfig::PlanarOrPanoramic, er.inlier_mask.clone())
        } else {
            (TwoViewConfig::Calibrated, er.inlier_mask.clone())
        }
    } else if let Some(fr) = f.as_ref().filter(|_| nf >= min) {
        if ratio(nh, nf) > opts.max_h_inlier_ratio {
            (TwoViewConfig::PlanarOrPanoramic, fr.inlier_mask.clone())
        } else {
            (TwoViewConfig::Uncalibrated, fr.inlier_mask.clone())
        }
    } else if let Some(hr) = h.as_ref().filter(|_| nh >= min) {
        (TwoViewConfig::PlanarOrPanoramic, hr.inlier_mask.clone())
    } else {
        return Ok(out);
    };
    out.config = config;
    out.num_inliers = mask.iter().filter(|m| **m).count();
    out.inlier_mask = mask;

    // Pose.
    match config {
        TwoViewConfig::Calibrated => {
            if let Some(em) = out.essential {
                let (p1, p2) = (masked(x1, &out.inlier_mask), masked(x2, &out.inlier_mask));
                if let Ok(pose) = pose_from_essential(&em, &p1, &p2) {
                    out.median_tri_angle_deg = median_tri_angle_deg(&pose);
                    out.cam2_from_cam1 = Some(pose.cam2_from_cam1);
                }
            }
        }
        TwoViewConfig::PlanarOrPanoramic => {
            if let Some(hr) = h.as_ref() {
                let (p1, p2) = (masked(x1, &hr.inlier_mask), masked(x2, &hr.inlier_mask));
                if let Ok(pose) = pose_from_homography(&hr.model, &p1, &p2) {
                    let angle = median_tri_angle_deg(&pose);
                    let pure_rotation = pose.cam2_from_cam1.translation.norm() == 0.0
                        || angle.is_none_or(|a| a < opts.max_panoramic_tri_angle_deg);
                    if pure_rotation {
                        out.config = TwoViewConfig::Panoramic;
                        out.cam2_from_cam1 = Some(Rigid3::new(pose.cam2_from_cam1.rotation, Vec3::zeros()));
                        out.median_tri_angle_deg = Some(angle.unwrap_or(0.0));
                    } else {
                        out.config = TwoViewConfig::Planar;
                        out.cam2_from_cam1 = Some(pose.cam2_from_cam1);
                        out.median_tri_angle_deg = angle;
                    }
                    if nh > out.num_inliers {
                        out.inlier_mask = hr.inlier_mask.clone();
                        out.num_inliers = nh;
                    }
                }
            }
        }
        _ => {}
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{
        planar_scene, random_rotation, relative_scene, relative_scene_with_pose, rotation_error_deg,
        translation_dir_error_deg,
    };
    use colslam_geometry::SplitMix64;

    const NOISE: f64 = 1.0 / 500.0;

    #[test]
    fn general_scene_is_calibrated() {
        let s = relative_scene(21, 500, NOISE, 0.3);
        let g = estimate_two_view_geometry(&s.x1, &s.x2, &TwoViewGeometryOptions::default()).unwrap();
        assert_eq!(g.config, TwoViewConfig::Calibrated);
        let pose = g.cam2_from_cam1.unwrap();
        assert!(rotation_error_deg(&pose, &s.cam2_from_cam1) < 0.3);
        assert!(translation_dir_error_deg(&pose.translation, &s.cam2_from_cam1.translation) < 3.0);
        assert!(g.median_tri_angle_deg.unwrap() > 3.0);
        assert!(g.num_inliers >= 330);
    }

    #[test]
    fn planar_scene_is_planar() {
        let s = planar_scene(5, 400, NOISE, 0.2);
        let g = estimate_two_view_geometry(&s.x1, &s.x2, &TwoViewGeometryOptions::default()).unwrap();
        assert_eq!(g.config, TwoViewConfig::Planar);
        assert!(g.cam2_from_cam1.is_some());
        assert!(g.num_inliers >= 300);
    }

    #[test]
    fn pure_rotation_is_panoramic() {
        let mut rng = SplitMix64::new(8);
        let pose = Rigid3::new(random_rotation(&mut rng, 0.2), Vec3::zeros());
        let s = relative_scene_with_pose(&mut rng, pose, 400, NOISE, 0.2, (2.0, 8.0));
        let g = estimate_two_view_geometry(&s.x1, &s.x2, &TwoViewGeometryOptions::default()).unwrap();
        assert_eq!(g.config, TwoViewConfig::Panoramic);
        let est = g.cam2_from_cam1.unwrap();
        assert_eq!(est.translation, Vec3::zeros());
        assert!(rotation_error_deg(&est, &pose) < 0.2);
    }

    #[test]
    fn tiny_baseline_is_panoramic() {
        let mut rng = SplitMix64::new(9);
        // 2 mm baseline, points 20-50 m away: angles ~0.005 deg.
        let pose = Rigid3::new(random_rotation(&mut rng, 0.2), Vec3::new(0.002, 0.0, 0.0));
        let s = relative_scene_with_pose(&mut rng, pose, 300, NOISE, 0.0, (20.0, 50.0));
        let g = estimate_two_view_geometry(&s.x1, &s.x2, &TwoViewGeometryOptions::default()).unwrap();
        assert_eq!(g.config, TwoViewConfig::Panoramic);
    }

    /// A wrong focal length in image 2 breaks the essential constraint but
    /// not the fundamental one.
    #[test]
    fn wrong_calibration_is_uncalibrated() {
        let mut s = relative_scene(23, 400, NOISE / 4.0, 0.1);
        for p in &mut s.x2 {
            *p *= 1.5;
        }
        let g = estimate_two_view_geometry(&s.x1, &s.x2, &TwoViewGeometryOptions::default()).unwrap();
        assert_eq!(
            g.config,
            TwoViewConfig::Uncalibrated,
            "E {} F {} H {}",
            g.num_inliers_e,
            g.num_inliers_f,
            g.num_inliers_h
        );
        assert!(g.cam2_from_cam1.is_none());
        assert!(g.num_inliers >= 340);
    }

    #[test]
    fn random_matches_are_degenerate() {
        let mut rng = SplitMix64::new(3);
        let mut r = || Vec2::new(rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6));
        let x1: Vec<Vec2> = (0..200).map(|_| r()).collect();
        let x2: Vec<Vec2> = (0..200).map(|_| r()).collect();
        let opts = TwoViewGeometryOptions {
            ransac: RansacOptions { max_error: 1e-3, ..TwoViewGeometryOptions::default().ransac },
            ..Default::default()
        };
        let g = estimate_two_view_geometry(&x1, &x2, &opts).unwrap();
        assert_eq!(g.config, TwoViewConfig::Degenerate);
    }

    #[test]
    fn degenerate_inputs() {
        let o = TwoViewGeometryOptions::default();
        let p = vec![Vec2::new(0.1, 0.1); 50];
        assert_eq!(estimate_two_view_geometry(&p, &p, &o).unwrap().config, TwoViewConfig::Degenerate);
        assert_eq!(estimate_two_view_geometry(&p[..3], &p[..3], &o).unwrap().config, TwoViewConfig::Degenerate);
        let line: Vec<Vec2> = (0..50).map(|i| Vec2::new(0.01 * i as f64, -0.005 * i as f64)).collect();
        assert_eq!(estimate_two_view_geometry(&line, &line, &o).unwrap().config, TwoViewConfig::Degenerate);
        let mut bad = p.clone();
        bad[7].x = f64::NAN;
        assert!(matches!(estimate_two_view_geometry(&bad, &p, &o), Err(EstimatorError::NonFinite { index: 7, .. })));
        assert!(estimate_two_view_geometry(&p, &p[..10], &o).is_err());
    }
}
