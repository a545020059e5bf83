//! Where the data lfit ships are found: `models/`, `configs/`, `checkpoints/` (and the label and
//! joint maps under `configs/maps/`). A relative path that does not exist in the working
//! directory is looked up, in this order, under
//! 1. `$LFIT_DATA_DIR` (one documented variable: a checkout or an installed data folder),
//! 2. the folder of the `lfit` executable (a release archive: `lfit` next to `models/` …),
//! 3. `<folder of the executable>/../share/lfit` (what `scripts/install.sh PREFIX` writes:
//!    `PREFIX/bin/lfit` and `PREFIX/share/lfit/{models,configs,checkpoints}`).
//!
//! No path of the build machine is compiled in: a binary copied elsewhere finds its data the same
//! way.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};

/// The environment variable naming a folder that holds `models/`, `configs/`, `checkpoints/`.
pub const DATA_DIR_VAR: &str = "LFIT_DATA_DIR";

/// The folders searched after the working directory, in order (those that can be named).
pub fn data_dirs() -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    if let Some(d) = std::env::var_os(DATA_DIR_VAR).filter(|d| !d.is_empty()) {
        dirs.push(PathBuf::from(d));
    }
    if let Some(exe_dir) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
    {
        let share = exe_dir.join("../share/lfit");
        dirs.push(exe_dir);
        dirs.push(share);
    }
    dirs
}

/// `path` as given when it exists or is absolute, else the first data folder holding it
/// ([`data_dirs`]); an error naming every place searched otherwise.
pub fn locate(path: &Path) -> Result<PathBuf> {
    if path.exists() || path.is_absolute() {
        return Ok(path.to_path_buf());
    }
    let dirs = data_dirs();
    if let Some(found) = dirs.iter().map(|d| d.join(path)).find(|p| p.exists()) {
        return Ok(found);
    }
    let searched: Vec<String> = dirs.iter().map(|d| d.display().to_string()).collect();
    let var = match std::env::var_os(DATA_DIR_VAR) {
        Some(_) => DATA_DIR_VAR.to_string(),
        None => format!("{DATA_DIR_VAR} (unset)"),
    };
    bail!(
        "{} not found in the working directory, {var} or next to the lfit executable ({}): run from the lfit checkout, set {DATA_DIR_VAR} to it, or install with scripts/install.sh",
        path.display(),
        searched.join(", ")
    )
}

/// [`locate`] for an input the user names: the found path, or the path as given when it is
/// found nowhere (the reader then reports it missing, as for any other file).
pub fn locate_or_given(path: &Path) -> PathBuf {
    locate(path).unwrap_or_else(|_| path.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn existing_and_absolute_paths_are_kept_and_missing_ones_name_the_places_searched() {
        // The unit tests run in the package root, where configs/ exists.
        let here = Path::new("configs/tuned.json");
        assert_eq!(locate(here).unwrap(), here);
        let abs = Path::new("/no/such/file.npz");
        assert_eq!(locate(abs).unwrap(), abs);
        let missing = Path::new("models/no-such-model-anywhere.npz");
        let err = locate(missing).unwrap_err().to_string();
        assert!(
            err.contains("models/no-such-model-anywhere.npz not found")
                && err.contains(DATA_DIR_VAR)
                && err.contains("share/lfit"),
            "{err}"
        );
        assert_eq!(locate_or_given(missing), missing);
    }
}
