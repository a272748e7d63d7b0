//! Outputs that a reader only ever sees whole.
//!
//! * [`write_atomic`] writes one file: a temporary file with a name unique to
//!   the call is written and synced beside the target, then renamed over it.
//! * [`OutputDir`] writes one folder (a COLMAP model, a run's outputs): every
//!   file goes into a staging folder beside the target, which is swapped in
//!   when complete, so the target always holds either the whole previous
//!   output or the whole new one, never a mix, and files of an earlier output
//!   (another format, more maps) never survive. A lock file beside the target
//!   refuses a second writer while the first runs.
//!
//! Names beside a target `OUT` (all hidden, in `OUT`'s parent folder):
//! `.OUT.lock` (the lock; holds the writer's pid), `.OUT.staging-PID-N` (the
//! new output while it is written; after the swap on Linux, the old one
//! until it is removed) and `.OUT.old-PID-N` (the old output between the
//! two renames of the swap where the file system cannot exchange two
//! folders atomically), and `.OUT.scratch-PID-N` (a writer's temporary
//! files, [`OutputDir::scratch_prefix`]). A writer killed at any point leaves some of these;
//! the next writer to the same target removes them (a lock whose process is
//! gone is stale and taken over) and, should the target be missing with an
//! `.OUT.old-*` beside it, first puts that complete previous output back.
//!
//! Whose files a target holds: [`OutputDir::begin`] is given the names the
//! writer owns and refuses a target folder holding anything else, so that
//! pointing an output at a folder of other files never deletes them.

use std::collections::HashSet;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard, OnceLock};

/// Why an output cannot be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The path names no folder that could be replaced.
    #[error("{path}: the output must name a folder (not `.`, `..` or a root)")]
    NoName {
        /// The output.
        path: PathBuf,
    },
    /// The output exists and is a file.
    #[error("{path}: the output exists and is not a folder")]
    NotAFolder {
        /// The output.
        path: PathBuf,
    },
    /// A folder on the way to the output is a file.
    #[error("{path}: cannot create the output: {file} is a file, not a folder")]
    UnderFile {
        /// The output.
        path: PathBuf,
        /// The ancestor that is a file.
        file: PathBuf,
    },
    /// The output folder holds files that are not the writer's.
    #[error(
        "{path}: the folder holds {entry}, which is not an output of this kind; refusing to replace it (choose a new \
         or empty folder, or remove what is not an output)"
    )]
    Foreign {
        /// The output.
        path: PathBuf,
        /// The first entry that is not the writer's.
        entry: String,
    },
    /// Another writer holds the output's lock.
    #[error(
        "{path}: another process ({holder}) is writing this output; wait for it to finish, or delete {lock} if no \
         such process runs"
    )]
    Locked {
        /// The output.
        path: PathBuf,
        /// The lock file.
        lock: PathBuf,
        /// Who holds it, as far as the lock says (`pid 123`).
        holder: String,
    },
    /// A file-system operation failed.
    #[error("{path}: cannot write the output: {action}")]
    Io {
        /// The output.
        path: PathBuf,
        /// What was being done (naming the file it was done to).
        action: String,
        /// The cause.
        source: std::io::Error,
    },
}

/// A name suffix no other call of this process (any thread) and no other
/// live process uses: the pid and a process-wide counter.
fn unique_suffix() -> String {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    format!("{}-{}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed))
}

/// Writes `bytes` to `path` atomically: a temporary file in the same folder,
/// named uniquely for this call (so concurrent writers of one path never
/// share it), is written and synced, then renamed over `path`, so a reader
/// never sees a partial file and an interrupted write leaves the old file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp-{}", unique_suffix()));
    let result = (|| {
        fault::step()?;
        let mut f = std::fs::File::create_new(&tmp)?;
        f.write_all(bytes)?;
        fault::step()?;
        f.sync_all()?;
        fault::step()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() && !fault::killed() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// A folder output being written: everything goes into [`OutputDir::path`]
/// (a staging folder beside the target), and [`OutputDir::commit`] swaps it
/// in. Dropped without a commit, the staging folder is removed and the
/// target is left as it was. The target's lock is held from
/// [`OutputDir::begin`] until the value is gone.
#[derive(Debug)]
pub struct OutputDir {
    target: PathBuf,
    staging: PathBuf,
    lock: PathBuf,
    committed: bool,
}

impl OutputDir {
    /// Starts writing the folder `target`, whose writer owns the entries
    /// named in `owned` (file or folder names directly in `target`). Checks,
    /// before anything is computed, that the output can be written: `target`
    /// must name a folder that is missing, empty or holds only `owned`
    /// entries, with no file on the way to it; its parent is created, the
    /// lock taken (refused while another live writer holds it) and the
    /// staging folder created, which proves the location writable.
    /// Leftovers of an interrupted earlier writer are removed.
    pub fn begin(target: &Path, owned: &[&str]) -> Result<Self, OutputError> {
        let target = resolve(target)?;
        let (parent, name) = parent_and_name(&target)?;
        check_location(&target)?;
        check_owned(&target, owned)?;
        let io = |action: String| {
            let path = target.clone();
            move |source| OutputError::Io { path, action, source }
        };
        std::fs::create_dir_all(&parent).map_err(io(format!("creating {}", parent.display())))?;
        let lock = parent.join(format!(".{name}.lock"));
        acquire_lock(&lock, &target)?;
        // From here on the lock is ours; dropping `out` releases it.
        let mut out = Self { target: target.clone(), staging: PathBuf::new(), lock, committed: false };
        clean_leftovers(&parent, &name, &target)?;
        // The target may have been changed by a writer that finished while we waited.
        check_owned(&target, owned)?;
        let staging = parent.join(format!(".{name}.staging-{}", unique_suffix()));
        fault::step().map_err(io(format!("creating {}", staging.display())))?;
        std::fs::create_dir(&staging).map_err(io(format!("creating {}", staging.display())))?;
        out.staging = staging;
        Ok(out)
    }

    /// Where a writer keeps temporary files beside the target while it
    /// works (a run's spilled frame records): the folder and the start of a
    /// name, to which the writer appends `PID-N` ([`std::process::id`] and
    /// a counter). The writer removes them; leftovers of a killed writer are
    /// removed by the next writer to the same target, as its staging folder.
    pub fn scratch_prefix(&self) -> (PathBuf, String) {
        let (parent, name) = match parent_and_name(&self.target) {
            Ok(pn) => pn,
            // `begin` resolved the same target: unreachable.
            Err(_) => (PathBuf::from("."), "out".into()),
        };
        (parent, format!(".{name}.scratch-"))
    }

    /// The folder to write into (the staging folder).
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// The folder that [`OutputDir::commit`] replaces.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Swaps the written folder in for the target: where the file system
    /// can, in one atomic exchange (Linux `renameat2(RENAME_EXCHANGE)`), else
    /// by renaming the old target aside and the new folder into place. The
    /// previous output is removed afterwards, and the lock released.
    pub fn commit(mut self) -> Result<(), OutputError> {
        let (parent, name) = parent_and_name(&self.target)?;
        let io = |action: String| {
            let path = self.target.clone();
            move |source| OutputError::Io { path, action, source }
        };
        fault::step().map_err(io(format!("syncing {}", self.staging.display())))?;
        sync_dir(&self.staging);
        fault::step().map_err(io(format!("moving {} into place", self.staging.display())))?;
        if std::fs::symlink_metadata(&self.target).is_err() {
            std::fs::rename(&self.staging, &self.target)
                .map_err(io(format!("renaming {} to the output", self.staging.display())))?;
            self.committed = true;
        } else if exchange(&self.staging, &self.target)
            .map_err(io(format!("exchanging {} with the output", self.staging.display())))?
        {
            // The staging path now holds the previous output.
            self.committed = true;
            fault::step().map_err(io(format!("removing the previous output {}", self.staging.display())))?;
            let _ = std::fs::remove_dir_all(&self.staging);
        } else {
            let aside = parent.join(format!(".{name}.old-{}", unique_suffix()));
            std::fs::rename(&self.target, &aside)
                .map_err(io(format!("moving the previous output aside to {}", aside.display())))?;
            fault::step().map_err(io(format!("renaming {} to the output", self.staging.display())))?;
            if let Err(e) = std::fs::rename(&self.staging, &self.target) {
                // Put the complete previous output back.
                let _ = std::fs::rename(&aside, &self.target);
                return Err(io(format!("renaming {} to the output", self.staging.display()))(e));
            }
            self.committed = true;
            fault::step().map_err(io(format!("removing the previous output {}", aside.display())))?;
            let _ = std::fs::remove_dir_all(&aside);
        }
        sync_dir(&parent);
        Ok(())
    }
}

impl Drop for OutputDir {
    fn drop(&mut self) {
        let mut held = held_locks();
        held.remove(&self.lock);
        if fault::killed() {
            // A simulated kill leaves everything as it is, the lock included.
            return;
        }
        if !self.committed && !self.staging.as_os_str().is_empty() {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
        let _ = std::fs::remove_file(&self.lock);
    }
}

/// The absolute form of `target`, through a symbolic link when it is one
/// (the folder it points to is the output; the link stays).
fn resolve(target: &Path) -> Result<PathBuf, OutputError> {
    let io = |action: &str| {
        let (path, action) = (target.to_path_buf(), action.to_string());
        move |source| OutputError::Io { path, action, source }
    };
    let abs = std::path::absolute(target).map_err(io("making the path absolute"))?;
    match std::fs::symlink_metadata(&abs) {
        Ok(m) if m.file_type().is_symlink() => std::fs::canonicalize(&abs).map_err(io("following the symbolic link")),
        _ => Ok(abs),
    }
}

fn parent_and_name(target: &Path) -> Result<(PathBuf, String), OutputError> {
    let no_name = || OutputError::NoName { path: target.to_path_buf() };
    let name = target.file_name().ok_or_else(no_name)?.to_string_lossy().into_owned();
    let parent = target.parent().ok_or_else(no_name)?.to_path_buf();
    Ok((parent, name))
}

/// The target is a folder or missing, and the nearest existing folder on
/// the way to it is a folder.
fn check_location(target: &Path) -> Result<(), OutputError> {
    if let Ok(m) = std::fs::metadata(target) {
        return if m.is_dir() { Ok(()) } else { Err(OutputError::NotAFolder { path: target.to_path_buf() }) };
    }
    for a in target.ancestors().skip(1) {
        if let Ok(m) = std::fs::metadata(a) {
            if !m.is_dir() {
                return Err(OutputError::UnderFile { path: target.to_path_buf(), file: a.to_path_buf() });
            }
            break;
        }
    }
    Ok(())
}

/// Every entry of an existing `target` is one of `owned`, or the temporary
/// file of one (left by an interrupted [`write_atomic`]).
fn check_owned(target: &Path, owned: &[&str]) -> Result<(), OutputError> {
    let Ok(entries) = std::fs::read_dir(target) else { return Ok(()) };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let is_tmp =
            |o: &&str| name.strip_prefix('.').and_then(|n| n.strip_prefix(*o)).is_some_and(|r| r.starts_with(".tmp-"));
        if !owned.contains(&name.as_str()) && !owned.iter().any(is_tmp) {
            return Err(OutputError::Foreign { path: target.to_path_buf(), entry: name });
        }
    }
    Ok(())
}

/// Lock files this process holds. Guarded by its mutex, taking and
/// releasing a lock is one step for the threads of this process, so a
/// thread never mistakes another's fresh lock (this pid) for a stale one.
fn held_locks() -> MutexGuard<'static, HashSet<PathBuf>> {
    static HELD: OnceLock<Mutex<HashSet<PathBuf>>> = OnceLock::new();
    HELD.get_or_init(Mutex::default).lock().unwrap_or_else(|e| e.into_inner())
}

/// A lock file without a pid (its writer died between creating and writing
/// it) is taken for held this long after it was made.
const UNREADABLE_LOCK_GRACE: std::time::Duration = std::time::Duration::from_secs(10);

/// Takes the lock `lock` of `target`: created with `create_new`, holding
/// this pid. A lock whose process is gone is stale and taken over.
fn acquire_lock(lock: &Path, target: &Path) -> Result<(), OutputError> {
    let io = |action: String| {
        let path = target.to_path_buf();
        move |source| OutputError::Io { path, action, source }
    };
    let mut held = held_locks();
    // Two tries: the second after removing a stale lock.
    for _ in 0..2 {
        fault::step().map_err(io(format!("creating the lock file {}", lock.display())))?;
        match std::fs::File::create_new(lock) {
            Ok(mut f) => {
                let written = f.write_all(format!("{}\n", std::process::id()).as_bytes()).and_then(|()| f.sync_all());
                if let Err(e) = written {
                    let _ = std::fs::remove_file(lock);
                    return Err(io(format!("writing the lock file {}", lock.display()))(e));
                }
                held.insert(lock.to_path_buf());
                return Ok(());
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let text = std::fs::read_to_string(lock).unwrap_or_default();
                let pid = text.trim().parse::<u32>().ok();
                let live = match pid {
                    Some(p) if p == std::process::id() => held.contains(lock),
                    Some(p) => process_alive(p),
                    None => std::fs::metadata(lock)
                        .and_then(|m| m.modified())
                        .ok()
                        .and_then(|t| t.elapsed().ok())
                        .is_some_and(|age| age < UNREADABLE_LOCK_GRACE),
                };
                if live {
                    let holder = pid.map_or_else(|| "pid unknown".to_string(), |p| format!("pid {p}"));
                    return Err(OutputError::Locked { path: target.to_path_buf(), lock: lock.to_path_buf(), holder });
                }
                match std::fs::remove_file(lock) {
                    Ok(()) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                    Err(e) => return Err(io(format!("removing the stale lock file {}", lock.display()))(e)),
                }
            }
            Err(e) => return Err(io(format!("creating the lock file {}", lock.display()))(e)),
        }
    }
    Err(OutputError::Locked { path: target.to_path_buf(), lock: lock.to_path_buf(), holder: "a new writer".into() })
}

/// Whether process `pid` runs. Linux answers through `/proc`; elsewhere
/// (or without `/proc`) every pid counts as running, so a stale lock is
/// reported rather than taken over.
fn process_alive(pid: u32) -> bool {
    let proc = Path::new("/proc");
    if cfg!(target_os = "linux") && proc.join("self").exists() { proc.join(pid.to_string()).exists() } else { true }
}

/// The suffix after `prefix` is `PID-N`, as [`unique_suffix`] makes it.
fn has_unique_suffix(name: &str, prefix: &str) -> bool {
    name.strip_prefix(prefix)
        .and_then(|r| r.split_once('-'))
        .is_some_and(|(a, b)| [a, b].iter().all(|s| !s.is_empty() && s.bytes().all(|c| c.is_ascii_digit())))
}

/// Removes the staging and aside folders of interrupted writers of
/// `target` (we hold its lock, so no live writer uses them). A missing
/// target with an aside folder beside it was interrupted inside the swap:
/// that folder is the complete previous output and is put back.
fn clean_leftovers(parent: &Path, name: &str, target: &Path) -> Result<(), OutputError> {
    let io = |action: String| {
        let path = target.to_path_buf();
        move |source| OutputError::Io { path, action, source }
    };
    let entries = std::fs::read_dir(parent).map_err(io(format!("listing {}", parent.display())))?;
    let (staging, old) = (format!(".{name}.staging-"), format!(".{name}.old-"));
    let scratch = format!(".{name}.scratch-");
    let mut leftovers: Vec<(bool, PathBuf)> = entries
        .flatten()
        .filter_map(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            let is_old = has_unique_suffix(&n, &old);
            let ours = has_unique_suffix(&n, &staging) || has_unique_suffix(&n, &scratch);
            (is_old || ours).then(|| (is_old, e.path()))
        })
        .collect();
    leftovers.sort();
    for (is_old, path) in leftovers {
        fault::step().map_err(io(format!("removing {}", path.display())))?;
        if is_old && std::fs::symlink_metadata(target).is_err() {
            std::fs::rename(&path, target).map_err(io(format!("restoring {}", path.display())))?;
        } else if path.is_dir() {
            std::fs::remove_dir_all(&path).map_err(io(format!("removing {}", path.display())))?;
        } else {
            std::fs::remove_file(&path).map_err(io(format!("removing {}", path.display())))?;
        }
    }
    Ok(())
}

/// Swaps two paths atomically; `Ok(false)` where the file system or the
/// platform cannot.
#[cfg(any(target_os = "linux", target_os = "android"))]
fn exchange(a: &Path, b: &Path) -> std::io::Result<bool> {
    use rustix::fs::{CWD, RenameFlags, renameat_with};
    use rustix::io::Errno;
    match renameat_with(CWD, a, CWD, b, RenameFlags::EXCHANGE) {
        Ok(()) => Ok(true),
        Err(e) if e == Errno::INVAL || e == Errno::NOSYS || e == Errno::OPNOTSUPP => Ok(false),
        Err(e) => Err(e.into()),
    }
}

/// Swaps two paths atomically; `Ok(false)` where the file system or the
/// platform cannot.
#[cfg(not(any(target_os = "linux", target_os = "android")))]
fn exchange(_: &Path, _: &Path) -> std::io::Result<bool> {
    Ok(false)
}

/// Makes a folder's entries durable (best effort: not every platform or
/// file system syncs folders, and the data itself is already synced).
fn sync_dir(dir: &Path) {
    if let Ok(f) = std::fs::File::open(dir) {
        let _ = f.sync_all();
    }
}

/// Fault injection for tests: simulates the process being killed at a
/// chosen file-system step of [`write_atomic`] and [`OutputDir`] on the
/// calling thread. The killed step and every later one fail without any
/// cleanup (temporary files, staging folders and the lock stay, as a kill
/// would leave them) until the plan is reset. Steps are counted only on the
/// thread that set a plan, so tests on other threads are unaffected. Not
/// part of the supported API.
#[doc(hidden)]
pub mod fault {
    use std::cell::Cell;

    #[derive(Clone, Copy, Default)]
    struct Plan {
        kill_at: Option<usize>,
        steps: usize,
        killed: bool,
    }

    thread_local! {
        static PLAN: Cell<Plan> = const { Cell::new(Plan { kill_at: None, steps: 0, killed: false }) };
    }

    /// From now on, this thread's step `k` (0-based) and every later one
    /// fail; `None` resets (no fault, count from 0).
    pub fn kill_at(k: Option<usize>) {
        PLAN.with(|p| p.set(Plan { kill_at: k, ..Plan::default() }));
    }

    /// Steps taken on this thread since the last [`kill_at`].
    pub fn steps() -> usize {
        PLAN.with(|p| p.get().steps)
    }

    /// Whether the simulated kill has happened on this thread.
    pub fn killed() -> bool {
        PLAN.with(|p| p.get().killed)
    }

    /// One file-system step: fails once the planned kill is reached.
    pub(crate) fn step() -> std::io::Result<()> {
        PLAN.with(|p| {
            let mut plan = p.get();
            if plan.kill_at == Some(plan.steps) {
                plan.killed = true;
            }
            plan.steps += 1;
            p.set(plan);
            if plan.killed { Err(std::io::Error::other("killed by fault injection")) } else { Ok(()) }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Names in `dir`, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .map(|r| r.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect())
            .unwrap_or_default();
        v.sort();
        v
    }

    fn write(out: &OutputDir, files: &[(&str, &str)]) {
        for (name, text) in files {
            write_atomic(&out.path().join(name), text.as_bytes()).unwrap();
        }
    }

    #[test]
    fn concurrent_atomic_writes_of_one_path_all_succeed_whole() {
        // Regression: one temporary name per process made threads of one
        // process share it ("No such file or directory", or a half-written
        // file published).
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("file.txt");
        let texts: Vec<Vec<u8>> = (0..20u8).map(|i| vec![b'a' + i; 200_000]).collect();
        std::thread::scope(|s| {
            let handles: Vec<_> = texts.iter().map(|t| s.spawn(|| write_atomic(&path, t))).collect();
            for h in handles {
                h.join().unwrap().unwrap();
            }
        });
        let got = std::fs::read(&path).unwrap();
        assert!(texts.contains(&got), "the file is one writer's whole text");
        assert_eq!(names(dir.path()), ["file.txt"], "no temporary file left");
    }

    #[test]
    fn a_committed_folder_replaces_the_old_one_whole() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        let owned = ["a.bin", "a.txt", "maps"];
        let out = OutputDir::begin(&target, &owned).unwrap();
        std::fs::create_dir(out.path().join("maps")).unwrap();
        write(&out, &[("a.bin", "old"), ("maps/x", "old")]);
        assert!(!target.exists(), "nothing is visible before the commit");
        out.commit().unwrap();
        assert_eq!(names(&target), ["a.bin", "maps"]);
        // A second output in another format: nothing of the first survives.
        let out = OutputDir::begin(&target, &owned).unwrap();
        write(&out, &[("a.txt", "new")]);
        assert_eq!(names(&target), ["a.bin", "maps"], "the old output stays until the commit");
        out.commit().unwrap();
        assert_eq!(names(&target), ["a.txt"]);
        assert_eq!(names(dir.path()), ["out"], "no lock, staging or aside folder left");
        // Dropped without a commit: the target is untouched, nothing left.
        let out = OutputDir::begin(&target, &owned).unwrap();
        write(&out, &[("a.bin", "dropped")]);
        drop(out);
        assert_eq!(names(&target), ["a.txt"]);
        assert_eq!(names(dir.path()), ["out"]);
    }

    #[test]
    fn bad_locations_are_refused_before_anything_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("file");
        std::fs::write(&file, "x").unwrap();
        let e = OutputDir::begin(&file, &[]).unwrap_err();
        assert!(matches!(e, OutputError::NotAFolder { .. }), "{e}");
        let e = OutputDir::begin(&file.join("sub").join("out"), &[]).unwrap_err();
        assert!(matches!(&e, OutputError::UnderFile { file: f, .. } if *f == file), "{e}");
        assert!(e.to_string().contains("is a file"), "{e}");
        let e = OutputDir::begin(Path::new("/"), &[]).unwrap_err();
        assert!(matches!(e, OutputError::NoName { .. }), "{e}");
        // A folder of other files is never replaced.
        let other = dir.path().join("photos");
        std::fs::create_dir(&other).unwrap();
        std::fs::write(other.join("holiday.jpg"), "x").unwrap();
        let e = OutputDir::begin(&other, &["a.bin"]).unwrap_err();
        assert!(matches!(&e, OutputError::Foreign { entry, .. } if entry == "holiday.jpg"), "{e}");
        // Leftover temporary files of an owned file are the writer's.
        let ours = dir.path().join("ours");
        std::fs::create_dir(&ours).unwrap();
        std::fs::write(ours.join("a.bin"), "x").unwrap();
        std::fs::write(ours.join(".a.bin.tmp-123"), "x").unwrap();
        OutputDir::begin(&ours, &["a.bin"]).unwrap().commit().unwrap();
        assert_eq!(names(&ours), Vec::<String>::new());
        assert_eq!(names(dir.path()), ["file", "ours", "photos"]);
    }

    #[test]
    fn a_held_lock_refuses_a_second_writer_and_a_stale_one_is_taken_over() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        let first = OutputDir::begin(&target, &[]).unwrap();
        let e = OutputDir::begin(&target, &[]).unwrap_err();
        assert!(matches!(&e, OutputError::Locked { holder, .. } if *holder == format!("pid {}", std::process::id())));
        assert!(e.to_string().contains(".out.lock"), "{e}");
        first.commit().unwrap();
        // The lock of a process that has exited is stale.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let dead = child.id();
        child.wait().unwrap();
        std::fs::write(dir.path().join(".out.lock"), format!("{dead}\n")).unwrap();
        std::fs::create_dir(dir.path().join(".out.staging-1-2")).unwrap();
        std::fs::write(dir.path().join(".out.staging-1-2").join("a.bin"), "x").unwrap();
        std::fs::create_dir(dir.path().join(".out.staging-x")).unwrap();
        let out = OutputDir::begin(&target, &[]).unwrap();
        let left = names(dir.path());
        assert!(!left.contains(&".out.staging-1-2".to_string()), "a dead writer's staging folder is removed");
        assert!(left.contains(&".out.staging-x".to_string()), "names not made by a writer are kept");
        out.commit().unwrap();
    }

    #[test]
    fn a_kill_inside_the_two_rename_swap_is_repaired_by_the_next_writer() {
        // Where folders cannot be exchanged, a kill between the renames
        // leaves the previous output aside and no target.
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        let aside = dir.path().join(".out.old-7-1");
        std::fs::create_dir(&aside).unwrap();
        std::fs::write(aside.join("a.bin"), "previous").unwrap();
        let out = OutputDir::begin(&target, &["a.bin"]).unwrap();
        assert_eq!(std::fs::read_to_string(target.join("a.bin")).unwrap(), "previous", "put back first");
        drop(out);
        assert_eq!(names(dir.path()), ["out"]);
    }

    #[test]
    fn a_writer_killed_at_any_step_leaves_one_whole_output() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out");
        let owned = ["a", "b", "c"];
        let publish = |text: &str| -> Result<(), OutputError> {
            let out = OutputDir::begin(&target, &owned)?;
            for name in owned {
                write_atomic(&out.path().join(name), text.as_bytes()).map_err(|source| OutputError::Io {
                    path: target.clone(),
                    action: name.into(),
                    source,
                })?;
            }
            out.commit()
        };
        publish("first").unwrap();
        fault::kill_at(Some(usize::MAX));
        publish("probe").unwrap();
        let steps = fault::steps();
        fault::kill_at(None);
        assert!(steps >= 12, "{steps} steps");
        for k in 0..steps {
            let previous = std::fs::read_to_string(target.join("a")).unwrap();
            fault::kill_at(Some(k));
            assert!(publish("killed").is_err(), "step {k}");
            fault::kill_at(None);
            let now: Vec<String> = owned.iter().map(|n| std::fs::read_to_string(target.join(n)).unwrap()).collect();
            assert!(now.iter().all(|t| *t == now[0]), "step {k}: a mixed output {now:?}");
            assert!([previous.as_str(), "killed"].contains(&now[0].as_str()), "step {k}: {now:?}");
            publish("after").unwrap();
            assert_eq!(names(dir.path()), ["out"], "step {k}: leftovers cleaned by the next writer");
            assert_eq!(names(&target), owned);
        }
    }
}
