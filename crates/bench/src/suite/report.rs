//! Rows of the suite report, their aggregation over repeated runs (median),
//! and the Markdown / JSON outputs.

use serde::Serialize;
use std::fmt::Write as _;

/// A run registering fewer frames than this share counts as failed
/// (design.md protocol).
pub const MIN_LOCALIZED_RATIO: f64 = 0.9;
/// Metres to centimetres.
const CM_PER_M: f64 = 100.0;

/// Outcome of one run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Finished and registered at least 90 % of the frames.
    Ok,
    /// Finished but registered under 90 % of the frames.
    LowRegistration,
    /// Crashed, failed or timed out (see `reason`).
    Failed,
    /// Not run (missing data or peer; see `reason`).
    NotRun,
}

impl Status {
    pub(crate) fn label(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::LowRegistration => "FAILED (<90 % localised)",
            Status::Failed => "FAILED",
            Status::NotRun => "not run",
        }
    }
}

/// One run of one system on one sequence.
#[derive(Debug, Clone, Serialize)]
pub struct RunRow {
    /// Sequence name.
    pub sequence: String,
    /// System ("colslam", "pycolmap 4.2.1 incremental", ...).
    pub system: String,
    /// Parameter setting of a sweep ("" for defaults), e.g. "skip=2".
    pub setting: String,
    /// Run number, from 1.
    pub run: usize,
    /// Outcome.
    pub status: Status,
    /// Why it failed or was not run.
    pub reason: Option<String>,
    /// Frames read.
    pub frames: Option<usize>,
    /// Frames localised.
    pub localized: Option<usize>,
    /// `localized / frames`, percent.
    pub localized_pct: Option<f64>,
    /// ATE RMSE over all localised frames (Sim(3) aligned), m.
    pub ate_rmse_m: Option<f64>,
    /// ATE RMSE over keyframes only, m.
    pub ate_kf_rmse_m: Option<f64>,
    /// Associated poses of the all-frames ATE.
    pub ate_matched: Option<usize>,
    /// Wall time of the process, s.
    pub wall_s: Option<f64>,
    /// CPU time (user + system) of the process, s.
    pub cpu_s: Option<f64>,
    /// Wall time per frame, ms.
    pub ms_per_frame: Option<f64>,
    /// Initialisation stage time, s (paper Table 2).
    pub init_s: Option<f64>,
    /// Registration + localisation stage time per frame, ms (paper Table 2).
    pub registration_ms_per_frame: Option<f64>,
    /// Peak resident memory, MiB.
    pub peak_rss_mib: Option<f64>,
    /// Keyframes (registered images for peers).
    pub keyframes: Option<usize>,
    /// 3D points.
    pub points: Option<usize>,
    /// Mean 3D points per keyframe.
    pub points_per_image: Option<f64>,
    /// Mean track length.
    pub mean_track_length: Option<f64>,
    /// Mean reprojection error, px.
    pub mean_reprojection_error_px: Option<f64>,
    /// Per-stage times of the run (report.json `timings_s` or the peer's).
    pub timings_s: Option<serde_json::Value>,
    /// Plot files, relative to the report folder.
    pub plots: Vec<String>,
    /// Output folder of the run, relative to the report folder.
    pub output_dir: String,
}

impl RunRow {
    /// An empty row with the identity fields set.
    pub fn new(sequence: &str, system: &str, setting: &str, run: usize, output_dir: String) -> Self {
        RunRow {
            sequence: sequence.to_string(),
            system: system.to_string(),
            setting: setting.to_string(),
            run,
            status: Status::Failed,
            reason: None,
            frames: None,
            localized: None,
            localized_pct: None,
            ate_rmse_m: None,
            ate_kf_rmse_m: None,
            ate_matched: None,
            wall_s: None,
            cpu_s: None,
            ms_per_frame: None,
            init_s: None,
            registration_ms_per_frame: None,
            peak_rss_mib: None,
            keyframes: None,
            points: None,
            points_per_image: None,
            mean_track_length: None,
            mean_reprojection_error_px: None,
            timings_s: None,
            plots: Vec::new(),
            output_dir,
        }
    }

    /// Sets `localized_pct` and the status from the counts (for a finished run).
    pub fn classify(&mut self) {
        match (self.frames, self.localized) {
            (Some(f), Some(l)) if f > 0 => {
                let ratio = l as f64 / f as f64;
                self.localized_pct = Some(100.0 * ratio);
                self.status = if ratio >= MIN_LOCALIZED_RATIO { Status::Ok } else { Status::LowRegistration };
            }
            _ => {
                self.status = Status::Failed;
                self.reason.get_or_insert_with(|| "no frames read".to_string());
            }
        }
    }
}

/// Medians of the runs of one (sequence, system, setting).
#[derive(Debug, Clone, Serialize)]
pub struct SummaryRow {
    /// Sequence name.
    pub sequence: String,
    /// System.
    pub system: String,
    /// Sweep setting ("" for defaults).
    pub setting: String,
    /// Runs attempted.
    pub runs: usize,
    /// Runs that finished (any registration).
    pub finished: usize,
    /// Runs with status ok.
    pub ok: usize,
    /// Status of the median: ok when most runs were ok.
    pub status: Status,
    /// First failure reason, if any.
    pub reason: Option<String>,
    /// Median over finished runs of each field of [`RunRow`].
    pub frames: Option<f64>,
    /// Median localised frames.
    pub localized: Option<f64>,
    /// Median localised percentage.
    pub localized_pct: Option<f64>,
    /// Median ATE RMSE, m.
    pub ate_rmse_m: Option<f64>,
    /// Median keyframe ATE RMSE, m.
    pub ate_kf_rmse_m: Option<f64>,
    /// Median wall time, s.
    pub wall_s: Option<f64>,
    /// Median CPU time, s.
    pub cpu_s: Option<f64>,
    /// Median ms per frame.
    pub ms_per_frame: Option<f64>,
    /// Median initialisation time, s.
    pub init_s: Option<f64>,
    /// Median registration ms per frame.
    pub registration_ms_per_frame: Option<f64>,
    /// Median peak RSS, MiB.
    pub peak_rss_mib: Option<f64>,
    /// Median keyframes.
    pub keyframes: Option<f64>,
    /// Median 3D points.
    pub points: Option<f64>,
    /// Median points per image.
    pub points_per_image: Option<f64>,
    /// Median track length.
    pub mean_track_length: Option<f64>,
    /// Median reprojection error, px.
    pub mean_reprojection_error_px: Option<f64>,
    /// Plots of the first finished run.
    pub plots: Vec<String>,
}

/// Median of the present finite values (mean of the two middle ones for an
/// even count); `None` when there is none (or the mean overflows).
pub fn median(values: impl IntoIterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = values.into_iter().flatten().collect();
    colslam_geometry::stats::median_finite(&v).filter(|m| m.is_finite())
}

/// Groups rows by (sequence, system, setting) in first-seen order and takes medians.
pub fn summarise(rows: &[RunRow]) -> Vec<SummaryRow> {
    let mut keys: Vec<(String, String, String)> = Vec::new();
    for r in rows {
        let k = (r.sequence.clone(), r.system.clone(), r.setting.clone());
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    keys.into_iter()
        .map(|(sequence, system, setting)| {
            let group: Vec<&RunRow> =
                rows.iter().filter(|r| r.sequence == sequence && r.system == system && r.setting == setting).collect();
            let done: Vec<&&RunRow> =
                group.iter().filter(|r| matches!(r.status, Status::Ok | Status::LowRegistration)).collect();
            let ok = group.iter().filter(|r| r.status == Status::Ok).count();
            let status = if group.iter().all(|r| r.status == Status::NotRun) {
                Status::NotRun
            } else if 2 * ok > group.len() {
                Status::Ok
            } else if !done.is_empty() {
                Status::LowRegistration
            } else {
                Status::Failed
            };
            let m = |f: &dyn Fn(&RunRow) -> Option<f64>| median(done.iter().map(|r| f(r)));
            let u = |x: Option<usize>| x.map(|v| v as f64);
            SummaryRow {
                runs: group.len(),
                finished: done.len(),
                ok,
                status,
                reason: group.iter().find_map(|r| r.reason.clone()),
                frames: m(&|r| u(r.frames)),
                localized: m(&|r| u(r.localized)),
                localized_pct: m(&|r| r.localized_pct),
                ate_rmse_m: m(&|r| r.ate_rmse_m),
                ate_kf_rmse_m: m(&|r| r.ate_kf_rmse_m),
                wall_s: m(&|r| r.wall_s),
                cpu_s: m(&|r| r.cpu_s),
                ms_per_frame: m(&|r| r.ms_per_frame),
                init_s: m(&|r| r.init_s),
                registration_ms_per_frame: m(&|r| r.registration_ms_per_frame),
                peak_rss_mib: m(&|r| r.peak_rss_mib),
                keyframes: m(&|r| u(r.keyframes)),
                points: m(&|r| u(r.points)),
                points_per_image: m(&|r| r.points_per_image),
                mean_track_length: m(&|r| r.mean_track_length),
                mean_reprojection_error_px: m(&|r| r.mean_reprojection_error_px),
                plots: done.first().map(|r| r.plots.clone()).unwrap_or_default(),
                sequence,
                system,
                setting,
            }
        })
        .collect()
}

/// A reference figure not measured by this run.
#[derive(Debug, Clone, Serialize)]
pub struct Reference {
    /// Sequence.
    pub sequence: &'static str,
    /// System.
    pub system: &'static str,
    /// Frames registered, as text.
    pub registered: &'static str,
    /// ATE RMSE, cm (None: not given).
    pub ate_cm: Option<f64>,
    /// Time, as text.
    pub time: &'static str,
    /// Where it comes from.
    pub source: &'static str,
}

/// Figures measured earlier on this machine (docs in /work/shared/design.md),
/// same data and protocol, not this run.
pub const MEASURED_EARLIER: [Reference; 4] = [
    Reference {
        sequence: "tum_fr1_rpy_sub",
        system: "COLMAP 3.8 CLI, SIFT + sequential + mapper",
        registered: "200/200",
        ate_cm: Some(2.25),
        time: "~1480 s wall in all",
        source: "measured earlier, not this run",
    },
    Reference {
        sequence: "tum_fr1_rpy_sub",
        system: "pycolmap 4.2.1, SIFT + sequential + global mapper (GLOMAP)",
        registered: "200/200",
        ate_cm: Some(2.32),
        time: "~270 s wall in all",
        source: "measured earlier, not this run",
    },
    Reference {
        sequence: "tum_fr1_rpy_sub",
        system: "pycolmap 4.2.1, SIFT + sequential + incremental mapper",
        registered: "192/200",
        ate_cm: Some(2.39),
        time: "~740 s wall in all",
        source: "measured earlier, not this run",
    },
    Reference {
        sequence: "tum_fr1_rpy_sub",
        system: "ORB-SLAM3 mono (self-trained vocabulary), 4 runs",
        registered: "loses tracking after 55-125 frames",
        ate_cm: None,
        time: "~25 ms per tracked frame (1.5-4.2 cm on what it tracked)",
        source: "measured earlier, not this run",
    },
];

/// The seed paper's own figures; none of these sequences is in our data.
pub const PAPER: [Reference; 4] = [
    Reference {
        sequence: "TUM fr1_xyz",
        system: "paper (ORB)",
        registered: "-",
        ate_cm: Some(10.93),
        time: "-",
        source: "paper; sequence not in our data",
    },
    Reference {
        sequence: "TUM fr2_xyz",
        system: "paper (ORB)",
        registered: "-",
        ate_cm: Some(0.26),
        time: "-",
        source: "paper; sequence not in our data",
    },
    Reference {
        sequence: "TUM fr1_desk",
        system: "paper (ORB)",
        registered: "-",
        ate_cm: Some(19.57),
        time: "-",
        source: "paper; sequence not in our data",
    },
    Reference {
        sequence: "(all)",
        system: "paper, ORB / learned features",
        registered: "-",
        ate_cm: None,
        time: "0.47 s per frame (ORB), 1.08 s (learned)",
        source: "paper",
    },
];

fn f(v: Option<f64>, decimals: usize) -> String {
    v.map_or_else(|| "-".to_string(), |x| format!("{x:.decimals$}"))
}

fn cm(v: Option<f64>) -> String {
    f(v.map(|m| m * CM_PER_M), 2)
}

fn system_label(s: &SummaryRow) -> String {
    if s.setting.is_empty() { s.system.clone() } else { format!("{} ({})", s.system, s.setting) }
}

/// The Markdown table of summary rows.
pub fn summary_table(rows: &[SummaryRow]) -> String {
    let mut t = String::new();
    t.push_str("| sequence | system | status | runs ok | localised | ATE all (cm) | ATE KF (cm) | wall (s) | CPU (s) | ms/frame | init (s) | reg. ms/frame | peak RSS (MiB) | KF | 3D points | pts/img | track len | reproj (px) |\n");
    t.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for s in rows {
        let loc = match (s.localized, s.frames, s.localized_pct) {
            (Some(l), Some(n), Some(p)) => format!("{l:.0}/{n:.0} ({p:.1} %)"),
            _ => "-".into(),
        };
        let _ = writeln!(
            t,
            "| {} | {} | {} | {}/{} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            s.sequence,
            system_label(s),
            s.status.label(),
            s.ok,
            s.runs,
            loc,
            cm(s.ate_rmse_m),
            cm(s.ate_kf_rmse_m),
            f(s.wall_s, 1),
            f(s.cpu_s, 1),
            f(s.ms_per_frame, 0),
            f(s.init_s, 2),
            f(s.registration_ms_per_frame, 1),
            f(s.peak_rss_mib, 0),
            f(s.keyframes, 0),
            f(s.points, 0),
            f(s.points_per_image, 0),
            f(s.mean_track_length, 2),
            f(s.mean_reprojection_error_px, 3),
        );
    }
    t
}

fn reference_table(refs: &[Reference]) -> String {
    let mut t =
        String::from("| sequence | system | registered | ATE RMSE (cm) | time | source |\n|---|---|---|---|---|---|\n");
    for r in refs {
        let _ = writeln!(
            t,
            "| {} | {} | {} | {} | {} | {} |",
            r.sequence,
            r.system,
            r.registered,
            f(r.ate_cm, 2),
            r.time,
            r.source
        );
    }
    t
}

/// Context of a suite run for the report header.
#[derive(Debug, Clone, Serialize)]
pub struct RunInfo {
    /// The command line.
    pub command: String,
    /// Suite name.
    pub suite: String,
    /// Runs per sequence.
    pub runs: usize,
    /// Start, seconds since the Unix epoch.
    pub started_unix_s: u64,
    /// Wall time of the whole suite, s.
    pub total_wall_s: f64,
    /// Logical CPUs.
    pub cpus: usize,
    /// /proc/loadavg at the start.
    pub load_start: String,
    /// /proc/loadavg at the end.
    pub load_end: String,
    /// Peers that ran or not, with reasons.
    pub peers: Vec<String>,
}

/// The `--feature-options` comparison: ORB + NN, XFeat + NN and XFeat +
/// LighterGlue on the same sequences (the paper's Table 2 columns).
#[derive(Debug, Clone, Serialize)]
pub struct FeatureOptions {
    /// Sequences compared.
    pub sequences: Vec<String>,
    /// (label, setting of its rows) per configuration; setting "" is the
    /// default run.
    pub configurations: Vec<(String, String)>,
    /// `--max-frames` of every configuration, if limited.
    pub max_frames: Option<usize>,
    /// `--num-features` of every configuration, if limited (default 2000).
    pub keypoints: Option<usize>,
    /// The table: one summary row per sequence and configuration, `system`
    /// replaced by the configuration label.
    pub rows: Vec<SummaryRow>,
}

/// The rows of the feature-options table, sequence by sequence, in
/// configuration order; a configuration without runs is a "not run" row.
pub fn feature_option_rows(fo: &FeatureOptions, summary: &[SummaryRow]) -> Vec<SummaryRow> {
    let mut out = Vec::new();
    for seq in &fo.sequences {
        for (label, setting) in &fo.configurations {
            let found = summary.iter().find(|r| &r.sequence == seq && r.system == "colslam" && &r.setting == setting);
            let mut row = match found {
                Some(r) => r.clone(),
                None => {
                    let mut r = summarise(&[RunRow::new(seq, label, setting, 1, String::new())]).remove(0);
                    r.status = Status::NotRun;
                    r.reason = Some("no run of this configuration".into());
                    r
                }
            };
            row.system = label.clone();
            out.push(row);
        }
    }
    out
}

/// The Markdown table of the feature options.
fn feature_options_table(fo: &FeatureOptions) -> String {
    let mut t = String::new();
    t.push_str("| sequence | configuration | status | runs ok | localised | ATE all (cm) | ATE KF (cm) | ms/frame | init (s) | reg. ms/frame | CPU (s) | peak RSS (MiB) | KF | 3D points | reproj (px) |\n");
    t.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for s in &fo.rows {
        let loc = match (s.localized, s.frames, s.localized_pct) {
            (Some(l), Some(n), Some(p)) => format!("{l:.0}/{n:.0} ({p:.1} %)"),
            _ => "-".into(),
        };
        let status = match (&s.reason, s.status) {
            (Some(r), Status::Failed | Status::NotRun) => format!("{}: {}", s.status.label(), r.replace('|', "/")),
            _ => s.status.label().to_string(),
        };
        let _ = writeln!(
            t,
            "| {} | {} | {} | {}/{} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            s.sequence,
            s.system,
            status,
            s.ok,
            s.runs,
            loc,
            cm(s.ate_rmse_m),
            cm(s.ate_kf_rmse_m),
            f(s.ms_per_frame, 0),
            f(s.init_s, 2),
            f(s.registration_ms_per_frame, 1),
            f(s.cpu_s, 1),
            f(s.peak_rss_mib, 0),
            f(s.keyframes, 0),
            f(s.points, 0),
            f(s.mean_reprojection_error_px, 3),
        );
    }
    t
}

/// The whole report.
#[derive(Debug, Clone, Serialize)]
pub struct SuiteReport {
    /// Context.
    pub info: RunInfo,
    /// Medians per sequence and system.
    pub summary: Vec<SummaryRow>,
    /// Every run.
    pub runs: Vec<RunRow>,
    /// The `--feature-options` table, when asked for.
    pub feature_options: Option<FeatureOptions>,
    /// Figures measured earlier (not this run).
    pub measured_earlier: Vec<Reference>,
    /// The paper's figures.
    pub paper: Vec<Reference>,
}

/// Renders `report.md`.
pub fn markdown(r: &SuiteReport) -> String {
    let i = &r.info;
    let mut s = String::new();
    let _ = writeln!(s, "# colslam sequence suite ({})\n", i.suite);
    let _ = writeln!(s, "Command: `{}`  ", i.command);
    let _ = writeln!(
        s,
        "Runs per sequence: {} (median reported). Machine: {} logical CPUs; load average at start `{}`, at end `{}`. Suite wall time {:.0} s.\n",
        i.runs, i.cpus, i.load_start, i.load_end, i.total_wall_s
    );
    s.push_str("ATE: RMSE after Sim(3) Umeyama alignment, as `evo_ape tum -as`, on all localised frames and on keyframes only. A run registering under 90 % of the frames counts as failed. init: initialisation stage time; reg. ms/frame: registration + localisation stage time per frame (the paper's Table 2 split). Wall, CPU and peak RSS are of the whole process.\n\n");
    s.push_str("## Results\n\n");
    s.push_str(&summary_table(&r.summary));
    let failures: Vec<&RunRow> = r.runs.iter().filter(|x| x.status != Status::Ok).collect();
    if !failures.is_empty() {
        s.push_str(
            "\n## Failures and runs not made\n\n| sequence | system | run | status | reason |\n|---|---|---|---|---|\n",
        );
        for x in failures {
            let label = if x.setting.is_empty() { x.system.clone() } else { format!("{} ({})", x.system, x.setting) };
            let reason = x.reason.clone().unwrap_or_else(|| match x.localized_pct {
                Some(p) => format!("{p:.1} % of frames localised"),
                None => "-".into(),
            });
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} |",
                x.sequence,
                label,
                x.run,
                x.status.label(),
                reason.replace('|', "/")
            );
        }
    }
    if let Some(fo) = &r.feature_options {
        s.push_str("\n## Feature options (the paper's Table 2 columns)\n\n");
        let mut limits = Vec::new();
        if let Some(n) = fo.max_frames {
            limits.push(format!("the first {n} frames"));
        }
        if let Some(n) = fo.keypoints {
            limits.push(format!("{n} keypoints per frame"));
        }
        let limits =
            if limits.is_empty() { "all frames, 2000 keypoints per frame".to_string() } else { limits.join(", ") };
        let _ = writeln!(
            s,
            "colslam with `--features orb --matcher nn` (the default), `--features xfeat --matcher nn` and `--features xfeat --matcher lighterglue`, each on {limits}.\n"
        );
        s.push_str(&feature_options_table(fo));
    }
    s.push_str("\n## Peers\n\n");
    if i.peers.is_empty() {
        s.push_str("No peers ran (pass `--peers`).\n");
    } else {
        for p in &i.peers {
            let _ = writeln!(s, "- {p}");
        }
    }
    s.push_str("\n## Measured earlier on the same data (not this run)\n\n");
    s.push_str(&reference_table(&r.measured_earlier));
    s.push_str("\n## The paper's figures (reference only: none of these sequences is in our data)\n\n");
    s.push_str(&reference_table(&r.paper));
    s.push_str("\n## Plots\n\n");
    for x in &r.summary {
        if !x.plots.is_empty() {
            let links: Vec<String> =
                x.plots.iter().map(|p| format!("[{}]({p})", p.rsplit('/').next().unwrap_or(p))).collect();
            let _ = writeln!(s, "- {} / {}: {}", x.sequence, system_label(x), links.join(", "));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians() {
        assert_eq!(median([Some(3.0), None, Some(1.0), Some(2.0)]), Some(2.0));
        assert_eq!(median([Some(4.0), Some(1.0)]), Some(2.5));
        assert_eq!(median([None]), None);
    }

    #[test]
    fn summary_status_and_failures() {
        let mut a = RunRow::new("s", "colslam", "", 1, "x".into());
        a.frames = Some(100);
        a.localized = Some(95);
        a.ate_rmse_m = Some(0.02);
        a.classify();
        assert_eq!(a.status, Status::Ok);
        let mut b = a.clone();
        b.run = 2;
        b.localized = Some(50);
        b.ate_rmse_m = Some(0.04);
        b.classify();
        assert_eq!(b.status, Status::LowRegistration);
        let mut c = RunRow::new("s", "colslam", "", 3, "y".into());
        c.reason = Some("panic (exit 101)".into());
        let mut d = RunRow::new("t", "colslam", "", 1, "z".into());
        d.status = Status::NotRun;
        let sum = summarise(&[a, b, c.clone(), d]);
        assert_eq!(sum.len(), 2);
        assert_eq!((sum[0].runs, sum[0].finished, sum[0].ok), (3, 2, 1));
        assert_eq!(sum[0].status, Status::LowRegistration);
        assert!((sum[0].ate_rmse_m.unwrap() - 0.03).abs() < 1e-12);
        assert_eq!(sum[1].status, Status::NotRun);
        let mut fo = FeatureOptions {
            sequences: vec!["s".into()],
            configurations: vec![
                ("ORB+NN".into(), String::new()),
                ("XFeat+LighterGlue".into(), "XFeat+LighterGlue".into()),
            ],
            max_frames: Some(40),
            keypoints: None,
            rows: Vec::new(),
        };
        fo.rows = feature_option_rows(&fo, &sum);
        assert_eq!(fo.rows.len(), 2);
        assert_eq!((fo.rows[0].system.as_str(), fo.rows[0].runs), ("ORB+NN", 3));
        assert_eq!((fo.rows[1].system.as_str(), fo.rows[1].status), ("XFeat+LighterGlue", Status::NotRun));
        let report = SuiteReport {
            info: RunInfo {
                command: "colslam bench".into(),
                suite: "quick".into(),
                runs: 3,
                started_unix_s: 0,
                total_wall_s: 1.0,
                cpus: 2,
                load_start: "1".into(),
                load_end: "1".into(),
                peers: vec![],
            },
            summary: sum.clone(),
            runs: vec![c],
            feature_options: Some(fo),
            measured_earlier: MEASURED_EARLIER.to_vec(),
            paper: PAPER.to_vec(),
        };
        let md = markdown(&report);
        assert!(md.contains("| s | colslam | FAILED (<90 % localised) | 1/3 |"), "{md}");
        assert!(md.contains("panic (exit 101)"));
        assert!(md.contains("10.93") && md.contains("2.25") && md.contains("not this run"));
        assert!(md.contains("## Feature options") && md.contains("the first 40 frames"), "{md}");
        assert!(md.contains("| s | ORB+NN | FAILED (<90 % localised) | 1/3 |"), "{md}");
        assert!(md.contains("| s | XFeat+LighterGlue | not run: no run of this configuration |"), "{md}");
    }
}
