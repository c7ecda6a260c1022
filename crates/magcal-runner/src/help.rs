//! The top-level help: the commands grouped by the task they serve, wrapped to the help's width;
//! and the shell's completions and the man page, made from the same command definition.

use std::io::Write;

use anyhow::{Context, Result};
use clap::builder::Command;

/// Widest help text, columns: clap wraps to the terminal up to this, and to this when the output
/// is not a terminal.
pub const HELP_WIDTH: usize = 100;

/// The commands by task, in the order a user meets them. Every command is in exactly one group
/// (a unit test checks it against the command definition).
pub const GROUPS: &[(&str, &[&str])] = &[
    ("Plan a vehicle's calibration", &["design", "simulate", "next"]),
    ("Calibrate a log", &["calibrate", "live", "apply", "export"]),
    ("Judge a calibration", &["evaluate", "replay"]),
    ("Look at a result", &["report", "plot"]),
    ("Reproduce and check [P1]", &["run", "check"]),
    ("Shell", &["completions", "man", "help"]),
];

/// `cmd` with a help template that lists its subcommands under [`GROUPS`], each with the first
/// sentence of its description, wrapped to [`HELP_WIDTH`].
#[must_use]
pub fn grouped(cmd: Command) -> Command {
    let cmd = cmd.max_term_width(HELP_WIDTH);
    let width = cmd.get_subcommands().map(|s| s.get_name().len()).max().unwrap_or(0);
    let mut listing = String::new();
    for (title, names) in GROUPS {
        listing.push_str(&format!("{title}:\n"));
        for name in *names {
            let about = if *name == "help" {
                "Print this message or the help of the given command".to_string()
            } else {
                cmd.find_subcommand(name)
                    .and_then(|s| s.get_about())
                    .map(|a| first_sentence(&a.to_string()))
                    .unwrap_or_default()
            };
            let indent = 2 + width + 2;
            for (i, line) in wrap(&about, HELP_WIDTH - indent).iter().enumerate() {
                if i == 0 {
                    listing.push_str(&format!("  {name:<width$}  {line}\n"));
                } else {
                    listing.push_str(&format!("{:indent$}{line}\n", ""));
                }
            }
        }
        listing.push('\n');
    }
    let template = format!(
        "{{before-help}}{{about-with-newline}}\n{{usage-heading}} {{usage}}\n\n{listing}Options:\n{{options}}{{after-help}}"
    );
    cmd.help_template(template)
}

/// The text up to the first full stop followed by a space (or all of it), with the stop.
fn first_sentence(text: &str) -> String {
    let text = text.split_whitespace().collect::<Vec<_>>().join(" ");
    match text.find(". ") {
        Some(i) => text[..=i].to_string(),
        None => text,
    }
}

/// `text` in lines of at most `width` characters, broken at spaces (a longer word stands alone).
fn wrap(text: &str, width: usize) -> Vec<String> {
    let mut lines = Vec::new();
    let mut line = String::new();
    for word in text.split_whitespace() {
        if !line.is_empty() && line.chars().count() + 1 + word.chars().count() > width {
            lines.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(word);
    }
    if !line.is_empty() || lines.is_empty() {
        lines.push(line);
    }
    lines
}

/// Writes the completion script of `shell` for `cmd` to `w`.
///
/// # Errors
/// A failed write.
pub fn completions(cmd: &mut Command, shell: clap_complete::Shell, w: &mut dyn Write) -> Result<()> {
    let mut bytes = Vec::new();
    clap_complete::generate(shell, cmd, "magcal", &mut bytes);
    w.write_all(&bytes).context("writing the completion script")
}

/// Writes the man page of `cmd` (roff, section 1) with a section per command to `w`.
///
/// # Errors
/// A failed write.
pub fn man(cmd: Command, w: &mut dyn Write) -> Result<()> {
    let mut bytes = Vec::new();
    let man = clap_mangen::Man::new(cmd.clone());
    man.render_title(&mut bytes)?;
    man.render_name_section(&mut bytes)?;
    man.render_synopsis_section(&mut bytes)?;
    man.render_description_section(&mut bytes)?;
    man.render_options_section(&mut bytes)?;
    for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()) {
        let name = format!("magcal {}", sub.get_name());
        writeln!(bytes, ".SH \"{}\"", name.to_uppercase())?;
        let page = clap_mangen::Man::new(sub.clone().bin_name(name));
        roff_section(&mut bytes, &page)?;
    }
    man.render_version_section(&mut bytes)?;
    w.write_all(&bytes).context("writing the man page")
}

/// One command's part of the man page: its name as a section heading, its description, synopsis
/// and options (clap_mangen renders a page per command; the sections of a subcommand's page are
/// what a section of the whole page holds).
fn roff_section(out: &mut Vec<u8>, page: &clap_mangen::Man) -> std::io::Result<()> {
    let mut part = Vec::new();
    page.render_synopsis_section(&mut part)?;
    page.render_description_section(&mut part)?;
    page.render_options_section(&mut part)?;
    // The subcommand's own top headings become subsections of its section.
    let text = String::from_utf8_lossy(&part).replace(".SH ", ".SS ");
    out.extend_from_slice(text.as_bytes());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_command_is_in_exactly_one_group_and_the_help_lists_it() {
        let mut cmd = crate::cli::command();
        cmd.build();
        let help = cmd.render_help().to_string();
        let mut names: Vec<&str> = cmd.get_subcommands().map(clap::Command::get_name).collect();
        let mut grouped: Vec<&str> = GROUPS.iter().flat_map(|(_, n)| n.iter().copied()).collect();
        names.sort_unstable();
        grouped.sort_unstable();
        assert_eq!(names, grouped);
        for name in &names {
            let listed = help.lines().filter(|l| l.starts_with(&format!("  {name} "))).count();
            assert_eq!(listed, 1, "{name} in\n{help}");
        }
        assert!(help.lines().all(|l| l.chars().count() <= HELP_WIDTH), "{help}");
    }

    #[test]
    fn words_wrap_at_spaces_within_the_width() {
        let lines = wrap("one two three four five six", 9);
        assert_eq!(lines, ["one two", "three", "four five", "six"]);
        assert_eq!(wrap("", 9), [""]);
        assert_eq!(wrap("unbreakableword x", 5), ["unbreakableword", "x"]);
    }

    #[test]
    fn the_first_sentence_ends_at_a_stop_and_a_space() {
        assert_eq!(first_sentence("Fit a log.  Then more."), "Fit a log.");
        assert_eq!(first_sentence("No stop here"), "No stop here");
        assert_eq!(
            first_sentence("A calibration.json (and more)"),
            "A calibration.json (and more)"
        );
    }
}
