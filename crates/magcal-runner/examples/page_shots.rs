//! Screenshots of a report page's figures, as the README shows them: opens PAGE.html in the
//! headless Chromium of the browser tests and writes one PNG per figure (`<id>.png`) into OUT_DIR,
//! or only those whose ids are given.
//!
//! `cargo run --release --example page_shots -- PAGE.html OUT_DIR [ID...]`

#[path = "../tests/it/browser.rs"]
#[allow(dead_code)]
mod browser;

use std::path::PathBuf;
use std::time::Duration;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [page, out, wanted @ ..] = args.as_slice() else {
        eprintln!("usage: page_shots PAGE.html OUT_DIR [ID...]");
        std::process::exit(2);
    };
    let Some(chrome) = browser::chromium() else {
        std::process::exit(2);
    };
    let opened = browser::open(&chrome, &PathBuf::from(page), Duration::from_secs(60));
    if !opened.errors.is_empty() {
        eprintln!("{page}: {:?}", opened.errors);
        std::process::exit(1);
    }
    let ids = opened.eval("Array.from(document.querySelectorAll('.plot, .figure, table')).map(e => e.id)");
    std::fs::create_dir_all(out).expect("OUT_DIR");
    for id in ids.as_array().into_iter().flatten().filter_map(|v| v.as_str()) {
        if id.is_empty() || (!wanted.is_empty() && !wanted.iter().any(|w| w == id)) {
            continue;
        }
        let path = PathBuf::from(out).join(format!("{id}.png"));
        opened.screenshot(&format!("#{id}")).save(&path).expect("PNG");
        println!("{}", path.display());
    }
    println!("{page}: drawn in {:.2} s", opened.seconds);
}
