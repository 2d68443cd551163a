//! A progress bar for long commands (simulate, run) that stays out of pipes and logs: it draws
//! on stderr only when stderr is a terminal, and is a silent no-op otherwise, so redirected
//! output and CI logs carry no control codes.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;

/// A labelled progress bar over `len` steps. Cleared when finished or dropped.
#[derive(Debug)]
pub struct Progress {
    bar: ProgressBar,
}

impl Progress {
    /// A bar for `len` steps, shown only if stderr is a terminal.
    pub fn new(len: u64, label: &str) -> Self {
        Self::with_visibility(len, label, std::io::stderr().is_terminal())
    }

    /// A bar for `len` steps, drawn on stderr when `visible`, silent otherwise.
    pub fn with_visibility(len: u64, label: &str, visible: bool) -> Self {
        if !visible {
            return Progress {
                bar: ProgressBar::hidden(),
            };
        }
        let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
        // The template is a literal known to parse; fall back to the default if it ever does not.
        let style = ProgressStyle::with_template(
            "{prefix:>12} [{bar:40}] {pos}/{len} ({percent}%) eta {eta} {msg}",
        )
        .map(|s| s.progress_chars("=> "))
        .unwrap_or_else(|_| ProgressStyle::default_bar());
        bar.set_style(style);
        bar.set_prefix(label.to_string());
        Progress { bar }
    }

    /// Whether anything is drawn.
    pub fn is_visible(&self) -> bool {
        !self.bar.is_hidden()
    }

    /// Advances by `n` steps.
    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
    }

    /// Sets the number of steps.
    pub fn set_length(&self, len: u64) {
        self.bar.set_length(len);
    }

    /// Sets the absolute position.
    pub fn set_position(&self, pos: u64) {
        self.bar.set_position(pos);
    }

    /// Current position (counted even when hidden).
    pub fn position(&self) -> u64 {
        self.bar.position()
    }

    /// Sets the text shown after the bar.
    pub fn set_message(&self, msg: impl Into<String>) {
        self.bar.set_message(msg.into());
    }

    /// Prints a line on stderr (above the bar when it is drawn).
    pub fn note(&self, line: &str) {
        if self.is_visible() {
            self.bar.println(line);
        } else {
            eprintln!("{line}");
        }
    }

    /// Removes the bar from the terminal.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if !self.bar.is_finished() {
            self.bar.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hidden_bar_counts_but_draws_nothing() {
        let p = Progress::with_visibility(10, "test", false);
        assert!(!p.is_visible());
        p.inc(3);
        p.inc(4);
        assert_eq!(p.position(), 7);
        p.set_position(10);
        assert_eq!(p.position(), 10);
        p.finish();
    }
}
