//! Folders of results (`demo --out-dir`, `lab report --out`): created if missing,
//! never a link, refused when they hold a previous run unless `--force`. The files in
//! them are written by the rule of single outputs ([`crate::write_bytes`],
//! [`crate::create_in_place`]).

use std::path::Path;

use crate::kind::{existing_kind, Kind};
use crate::whole::check_output;
use crate::{Error, Result};

fn refused(dir: &Path, problem: String) -> Error {
    Error::FolderRefused {
        path: dir.to_path_buf(),
        problem,
    }
}

/// Refuses a folder of results that is not a folder (a symbolic link to one
/// included: it is not followed), or that holds any of `files` from a previous run
/// without `force`; each of `files` is then checked as a single output
/// ([`check_output`]). A missing folder is accepted ([`create_dir`] makes it).
pub fn check_dir(dir: &Path, files: &[&str], force: bool) -> Result<()> {
    match existing_kind(dir) {
        Ok(None) => return Ok(()),
        Ok(Some(Kind::Directory)) => {}
        Ok(Some(kind)) => return Err(refused(dir, kind.folder_refusal(dir))),
        Err(e) => return Err(refused(dir, format!("cannot inspect it: {e}"))),
    }
    let previous: Vec<&str> = files
        .iter()
        .copied()
        .filter(|f| std::fs::symlink_metadata(dir.join(f)).is_ok())
        .collect();
    if !previous.is_empty() && !force {
        return Err(refused(
            dir,
            format!(
                "holds a previous run ({}); pass --force to overwrite it",
                previous.join(", ")
            ),
        ));
    }
    for f in files {
        check_output(&dir.join(f), &[], force)?;
    }
    Ok(())
}

/// Creates the folder [`check_dir`] accepted (and missing parents), and makes sure
/// what stands there afterwards is a folder, not a link made meanwhile.
pub fn create_dir(dir: &Path) -> Result<()> {
    match existing_kind(dir) {
        Ok(Some(Kind::Directory)) => return Ok(()),
        Ok(Some(kind)) => return Err(refused(dir, kind.folder_refusal(dir))),
        Ok(None) => {}
        Err(e) => return Err(refused(dir, format!("cannot inspect it: {e}"))),
    }
    std::fs::DirBuilder::new()
        .recursive(true)
        .create(dir)
        .map_err(|e| refused(dir, format!("cannot create it: {e}")))?;
    match existing_kind(dir) {
        Ok(Some(Kind::Directory)) => Ok(()),
        Ok(Some(kind)) => Err(refused(dir, kind.folder_refusal(dir))),
        Ok(None) => Err(refused(
            dir,
            "removed as soon as it was created".to_string(),
        )),
        Err(e) => Err(refused(dir, format!("cannot inspect it: {e}"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_folder_of_results_is_never_a_link_and_a_previous_run_needs_force() {
        let dir = tempfile::TempDir::new().unwrap();
        let out = dir.path().join("report");
        check_dir(&out, &["index.html"], false).unwrap();
        create_dir(&out).unwrap();
        crate::write_bytes(&out.join("index.html"), false, b"one").unwrap();
        let e = check_dir(&out, &["index.html", "x.svg"], false)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            format!(
                "output folder {}: holds a previous run (index.html); pass --force to overwrite it",
                out.display()
            )
        );
        check_dir(&out, &["index.html"], true).unwrap();
        // A link to a folder, and a dangling one: refused, and nothing made there.
        let elsewhere = dir.path().join("elsewhere");
        std::fs::create_dir(&elsewhere).unwrap();
        let missing = dir.path().join("missing");
        for (name, to) in [("link", &elsewhere), ("dangling", &missing)] {
            let link = dir.path().join(name);
            std::os::unix::fs::symlink(to, &link).unwrap();
            for force in [false, true] {
                let e = check_dir(&link, &["index.html"], force)
                    .unwrap_err()
                    .to_string();
                assert!(
                    e.contains(": is a symbolic link to") && e.contains("name the folder itself"),
                    "{e}"
                );
            }
            assert!(create_dir(&link).is_err());
        }
        assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0);
        assert!(!missing.exists());
        let e = check_dir(Path::new("/dev/null"), &["x"], true)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "output folder /dev/null: exists and is a character device, not a folder"
        );
    }
}
