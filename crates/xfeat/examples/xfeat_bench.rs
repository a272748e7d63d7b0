//! Times XFeat extraction and matching on real frames.
//!
//! `RAYON_NUM_THREADS=2 cargo run --release -p colslam-xfeat --example xfeat_bench -- <rgb dir> [frames] [extract]`
//! (weights from `COLSLAM_XFEAT_WEIGHTS` or the peer venv, see `find_weights`).

use colslam_features::{FeatureExtractor, Matcher, NnMatcher, NnMatcherOptions};
use colslam_geometry::stats::upper_median_in_place;
use colslam_image::Image;
use colslam_xfeat::{
    LighterGlue, LighterGlueOptions, MnnCosineMatcher, MnnCosineOptions, XFeat, XFeatModel, XFeatOptions, find_weights,
};
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    upper_median_in_place(&mut v).expect("median of an empty sample")
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let dir = args.get(1).ok_or("usage: xfeat_bench <rgb dir> [frames]")?;
    let count: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(10);
    // A third argument "extract" skips the matchers (for profiling).
    let extract_only = args.get(3).is_some_and(|a| a == "extract");
    let mut names: Vec<_> = std::fs::read_dir(dir)?.filter_map(|e| e.ok().map(|e| e.path())).collect();
    names.sort();
    let imgs: Vec<Image> = names.iter().take(count).map(|p| Image::read(p)).collect::<Result<_, _>>()?;
    let model = XFeatModel::load(&find_weights()?)?;
    println!(
        "{} frames {}x{}, {} rayon threads",
        imgs.len(),
        imgs[0].width(),
        imgs[0].height(),
        rayon::current_num_threads()
    );
    for top_k in [1000, 2000] {
        let xf = XFeat::with_model(model.clone(), XFeatOptions { top_k, ..Default::default() })?;
        let _ = xf.extract(&imgs[0])?; // warm-up
        let mut times = Vec::new();
        let mut feats = Vec::new();
        for img in &imgs {
            let t = Instant::now();
            let f = xf.extract(img)?;
            times.push(t.elapsed().as_secs_f64() * 1e3);
            feats.push(f);
        }
        let mean_n = feats.iter().map(|f| f.len()).sum::<usize>() as f64 / feats.len() as f64;
        println!("top_k {top_k}: extraction median {:.1} ms/frame, mean {mean_n:.0} keypoints", median(times));
        if extract_only {
            continue;
        }
        let mnn = MnnCosineMatcher::new(MnnCosineOptions::default())?;
        let nn = NnMatcher::new(NnMatcherOptions { max_ratio: 1.0, ..Default::default() })?;
        let lg = LighterGlue::new(LighterGlueOptions {
            image_size: Some([imgs[0].width(), imgs[0].height()]),
            ..Default::default()
        })?;
        for (name, m) in
            [("xfeat-mnn", &mnn as &dyn Matcher), ("features nn (L2, cross-check)", &nn), ("lighterglue", &lg)]
        {
            let mut times = Vec::new();
            let mut counts = Vec::new();
            for w in feats.windows(2) {
                let t = Instant::now();
                let ms = m.match_features(&w[0], &w[1])?;
                times.push(t.elapsed().as_secs_f64() * 1e3);
                counts.push(ms.len() as f64);
            }
            println!("  {name}: median {:.2} ms/pair, median {:.0} matches", median(times), median(counts));
        }
    }
    Ok(())
}
