//! Where a campaign may read and write: its stage model (inside the allowed directories for a
//! submitted file, symlinks followed) and its output directory (probed writable at validation).
use std::path::{Path, PathBuf};

use super::*;

/// Resolves the stage model a campaign names and reads it (at most 1 MiB, a regular file).
/// Submitted campaigns: the path resolves from the policy's base directory and must stay inside
/// one of its read roots, symlinks followed; errors never show a server path or the file.
pub(super) fn load_model(m: &str, trust: &Trust) -> Result<LoadedModel, ModelLoadError> {
    if m.is_empty() || m.len() > MAX_PATH_LEN || m.contains('\0') {
        return Err(ModelLoadError::Name);
    }
    let policy = match trust {
        Trust::Stored {
            model_toml: Some(text),
            ..
        } => {
            let model =
                csmetro_sim::StageModel::from_toml_str(text).map_err(ModelLoadError::Stored)?;
            return Ok(LoadedModel {
                model,
                text: text.clone(),
            });
        }
        Trust::Local { base_dir }
        | Trust::Stored {
            base_dir,
            model_toml: None,
        } => {
            let p = if Path::new(m).is_absolute() {
                PathBuf::from(m)
            } else {
                base_dir.join(m)
            };
            let text = read_bounded(&p, MAX_TOML_BYTES).map_err(|source| ModelLoadError::Read {
                path: p.display().to_string(),
                source,
            })?;
            let model = csmetro_sim::StageModel::from_toml_str(&text).map_err(|source| {
                ModelLoadError::Parse {
                    path: p.display().to_string(),
                    source,
                }
            })?;
            return Ok(LoadedModel { model, text });
        }
        Trust::Submitted(p) => p,
    };
    // The value is not repeated (no variant below holds it): it may be a server path the
    // client is probing for.
    let outside = || ModelLoadError::Outside;
    let rel = Path::new(m);
    if rel.extension().is_none_or(|e| e != "toml") {
        return Err(ModelLoadError::NotToml);
    }
    use std::path::Component;
    if rel
        .components()
        .any(|c| matches!(c, Component::RootDir | Component::Prefix(_)))
    {
        return Err(outside());
    }
    let joined = normalize(&policy.base_dir.join(rel));
    let root = policy
        .read_roots
        .iter()
        .map(|r| normalize(r))
        .find(|r| joined.starts_with(r))
        .ok_or_else(outside)?;
    // Symlinks: what the OS opens must still be inside the root.
    let real = joined.canonicalize().map_err(ModelLoadError::Resolve)?;
    let real_root = root.canonicalize().map_err(|_| outside())?;
    if !real.starts_with(&real_root) {
        return Err(outside());
    }
    let text = read_bounded(&real, MAX_TOML_BYTES).map_err(ModelLoadError::ReadSubmitted)?;
    // The TOML syntax error would quote the file's line: give only where it is.
    if let Err(e) = toml::from_str::<toml::Table>(&text) {
        let line = e.span().map(|s| line_of(&text, s.start)).unwrap_or(0);
        return Err(ModelLoadError::Syntax(line));
    }
    // Only where, never what: the message would quote the file's own keys and values.
    let model = csmetro_sim::StageModel::from_toml_str(&text).map_err(|e| match e {
        csmetro_sim::ModelError::Line { line, .. } => ModelLoadError::InvalidAt(line),
        _ => ModelLoadError::Invalid,
    })?;
    Ok(LoadedModel { model, text })
}

/// Why a campaign's stage model was not loaded. A submitted file's errors (from `NotToml` on)
/// never show its path or its content: only "the stage model" and a line number.
#[derive(Debug, thiserror::Error)]
pub(super) enum ModelLoadError {
    #[error("must be a file name of 1..={MAX_PATH_LEN} bytes")]
    Name,
    #[error("the stored stage model: {0}")]
    Stored(csmetro_sim::ModelError),
    #[error("{path}: {source}")]
    Read {
        path: String,
        source: crate::tomlpos::ReadError,
    },
    #[error("{path}: {source}")]
    Parse {
        path: String,
        source: csmetro_sim::ModelError,
    },
    #[error("the stage model must be a .toml file")]
    NotToml,
    #[error(
        "the stage model must be a relative path inside the service's campaign or model \
         directories (e.g. \"demo_xy.toml\")"
    )]
    Outside,
    #[error("the stage model: {}", io_reason(.0))]
    Resolve(std::io::Error),
    #[error("the stage model: {0}")]
    ReadSubmitted(crate::tomlpos::ReadError),
    #[error("the stage model: not a stage model (TOML error at line {0})")]
    Syntax(usize),
    #[error("the stage model: not a valid stage model (see its line {0})")]
    InvalidAt(usize),
    #[error("the stage model: not a valid stage model")]
    Invalid,
}

/// `a/./b/../c` → `a/c`, without touching the file system.
fn normalize(p: &Path) -> PathBuf {
    use std::path::Component;
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other.as_os_str()),
        }
    }
    out
}

/// An output directory template a submitted campaign may use: relative, plain components.
pub(super) fn check_submitted_outputs(dir: &str) -> Result<(), OutsideResults> {
    use std::path::Component;
    let p = Path::new(dir);
    if dir.contains('\0')
        || p.components()
            .any(|c| !matches!(c, Component::Normal(_) | Component::CurDir))
    {
        return Err(OutsideResults);
    }
    Ok(())
}

/// A submitted campaign's output directory that would leave the service's results directory.
#[derive(Debug, thiserror::Error)]
#[error(
    "a submitted campaign writes below the service's results directory: give a relative \
     directory without `..`"
)]
pub(super) struct OutsideResults;

/// The output directory must be writable before anything moves: the fixed part of the template
/// (before the first `{id}`/`{name}`) is created and a probe file written; for the local operator
/// the directories the probe created are removed again.
pub(super) fn probe_outputs(
    template: &str,
    root: Option<&Path>,
    fail: &dyn Fn(&str, String) -> SpecError,
) -> Result<(), SpecError> {
    let fixed: PathBuf = Path::new(template)
        .components()
        .take_while(|c| !c.as_os_str().to_string_lossy().contains('{'))
        .collect();
    let dir = match root {
        Some(r) => r.join(&fixed),
        None if fixed.as_os_str().is_empty() => PathBuf::from("."),
        None => fixed,
    };
    // Submitted campaigns: the error must not show the server's path.
    let shown = |e: &std::io::Error| match root {
        Some(_) => format!("the results directory is not writable ({})", io_reason(e)),
        None => format!("{} is not writable: {}", dir.display(), io_reason(e)),
    };
    let mut created = Vec::new();
    let mut d = dir.as_path();
    while !d.as_os_str().is_empty() && !d.exists() {
        created.push(d.to_path_buf());
        match d.parent() {
            Some(p) => d = p,
            None => break,
        }
    }
    let result = std::fs::create_dir_all(&dir).and_then(|()| {
        // Unique per probe: the service validates submissions on several threads at once.
        static PROBES: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let k = PROBES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let probe = dir.join(format!(".csmetro-probe-{}-{k}", std::process::id()));
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&probe)
            .and_then(|mut f| std::io::Write::write_all(&mut f, b"probe"))?;
        std::fs::remove_file(&probe)
    });
    // The operator's directories are left as they were. Below the service's results directory
    // they stay: another submission may be probing the same directory at this moment.
    if root.is_none() {
        for c in &created {
            let _ = std::fs::remove_dir(c);
        }
    }
    result.map_err(|e| fail("outputs.dir", shown(&e)))
}
