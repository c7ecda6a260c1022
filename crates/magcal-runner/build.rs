//! Records how the binary was built, for `run.json` and the calibration manifest: rustc version,
//! target, git revision.
use std::process::Command;

fn main() {
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let version = Command::new(rustc)
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=MAGCAL_RUSTC_VERSION={version}");
    println!(
        "cargo:rustc-env=MAGCAL_TARGET={}",
        std::env::var("TARGET").unwrap_or_default()
    );
    let git = |args: &[&str]| {
        Command::new("git")
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .and_then(|o| String::from_utf8(o.stdout).ok())
            .map(|s| s.trim().to_string())
    };
    let revision = match git(&["rev-parse", "HEAD"]) {
        Some(rev) => {
            let dirty = git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
            if dirty { format!("{rev}-dirty") } else { rev }
        }
        None => "unknown".into(),
    };
    println!("cargo:rustc-env=MAGCAL_GIT_REVISION={revision}");
    // Run again when the checked-out commit changes, and when the sources do (so that `-dirty`
    // is as of the build). Git names its files: `.git` is a file in a worktree, and a commit
    // moves the branch's ref, not `HEAD`. Not the index, which `git status` rewrites: that would
    // rebuild the binary after every look at the tree.
    let mut watched = vec!["HEAD".to_string(), "packed-refs".to_string()];
    watched.extend(git(&["symbolic-ref", "-q", "HEAD"]));
    for name in watched {
        if let Some(path) = git(&["rev-parse", "--path-format=absolute", "--git-path", &name])
            && std::path::Path::new(&path).exists()
        {
            println!("cargo:rerun-if-changed={path}");
        }
    }
    for sources in ["src", "../magcal-core/src"] {
        println!("cargo:rerun-if-changed={sources}");
    }
    println!("cargo:rerun-if-changed=build.rs");
}
