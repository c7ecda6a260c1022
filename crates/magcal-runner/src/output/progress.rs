//! Progress bars on standard error, for [`crate::pipeline::Progress`]: a spinner for a stage
//! without a count, a bar with the time left for one with a count; nothing when not shown.

use indicatif::{ProgressBar, ProgressStyle};

use crate::pipeline::Progress;

/// Bars drawn on standard error when `show` (an interactive terminal and no `--quiet`).
#[derive(Debug, Clone, Copy)]
pub struct Bars {
    /// Draw them.
    pub show: bool,
}

impl Progress for Bars {
    fn stage(&self, message: &str, len: Option<u64>) -> ProgressBar {
        if !self.show {
            return ProgressBar::hidden();
        }
        let message = message.to_string();
        match len {
            None => {
                let bar = ProgressBar::new_spinner().with_message(message);
                bar.set_style(ProgressStyle::with_template("{spinner} {msg} [{elapsed}]").expect("valid template"));
                bar.enable_steady_tick(std::time::Duration::from_millis(120));
                bar
            }
            Some(len) => {
                let bar = ProgressBar::new(len).with_message(message);
                bar.set_style(
                    ProgressStyle::with_template("{msg} {bar:40} {pos}/{len} [{elapsed} < {eta}]")
                        .expect("valid template"),
                );
                bar
            }
        }
    }
}
