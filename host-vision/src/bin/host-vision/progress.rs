//! Progress bars on stderr: drawn only once their length is known (never `0/0`), always
//! labelled, and as wide as the terminal (a long label is cut, the line never wraps).

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A bar made on first use.
pub struct Bar {
    template: &'static str,
    target: Option<Box<dyn Fn() -> ProgressDrawTarget>>,
    bar: Option<ProgressBar>,
}

impl Bar {
    /// A bar with `template` (indicatif's; `{wide_msg}` or `{wide_bar}` make it fit).
    pub fn new(template: &'static str) -> Self {
        Bar {
            template,
            target: None,
            bar: None,
        }
    }

    /// Draws to `target` instead of stderr (for tests).
    #[cfg(test)]
    pub fn with_target(mut self, target: impl Fn() -> ProgressDrawTarget + 'static) -> Self {
        self.target = Some(Box::new(target));
        self
    }

    /// Shows `done` of `total` with `label`; a new label starts the bar afresh.
    pub fn update(&mut self, label: &str, done: u64, total: u64) {
        if total == 0 {
            return;
        }
        let bar = match &self.bar {
            Some(b) => b,
            None => {
                let b = ProgressBar::with_draw_target(
                    Some(total),
                    self.target
                        .as_ref()
                        .map_or_else(ProgressDrawTarget::stderr, |t| t()),
                );
                if let Ok(style) = ProgressStyle::with_template(self.template) {
                    b.set_style(style.progress_chars("=> "));
                }
                self.bar.insert(b)
            }
        };
        if bar.message() != label {
            bar.set_message(label.to_string());
            bar.reset();
        }
        bar.set_length(total);
        bar.set_position(done);
    }

    /// Prints `line` on stdout without tearing the bar.
    pub fn say(&self, line: &str) {
        match &self.bar {
            Some(b) => b.suspend(|| crate::console::say!("{line}")),
            None => crate::console::say!("{line}"),
        }
    }

    /// Leaves the finished bar on screen.
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish();
        }
    }

    /// Removes the bar.
    pub fn clear(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use indicatif::TermLike;

    use super::*;

    /// A terminal of a given width that records what is drawn.
    #[derive(Debug, Clone)]
    struct Term {
        width: u16,
        lines: Arc<Mutex<Vec<String>>>,
    }

    impl TermLike for Term {
        fn width(&self) -> u16 {
            self.width
        }
        fn move_cursor_up(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn move_cursor_down(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn move_cursor_right(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn move_cursor_left(&self, _: usize) -> std::io::Result<()> {
            Ok(())
        }
        fn write_line(&self, s: &str) -> std::io::Result<()> {
            self.lines.lock().unwrap().push(s.to_string());
            Ok(())
        }
        fn write_str(&self, s: &str) -> std::io::Result<()> {
            self.lines.lock().unwrap().push(s.to_string());
            Ok(())
        }
        fn clear_line(&self) -> std::io::Result<()> {
            Ok(())
        }
        fn flush(&self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn drawn(template: &'static str, width: u16, label: &str) -> Vec<String> {
        let term = Term {
            width,
            lines: Arc::default(),
        };
        let t = term.clone();
        let mut bar = Bar::new(template)
            .with_target(move || ProgressDrawTarget::term_like_with_hz(Box::new(t.clone()), 200));
        bar.update(label, 0, 0);
        assert!(
            term.lines.lock().unwrap().is_empty(),
            "drawn before its length was known"
        );
        bar.update(label, 123_456, 1_234_567);
        bar.finish();
        term.lines.lock().unwrap().clone()
    }

    #[test]
    fn every_bar_fits_the_terminal_and_is_labelled() {
        let long = "track acc: 1234 frames, DeadReckoning since the start of the data";
        for (template, label) in [
            (crate::TRACK_BAR, long),
            (crate::SYNTH_BAR, "synth desktop-fast"),
            (crate::EVAL_BAR, "desktop-slow gravity-2features"),
        ] {
            for width in [60u16, 100, 200] {
                let lines = drawn(template, width, label);
                assert!(!lines.is_empty());
                for l in &lines {
                    let chars = console_width(l);
                    assert!(chars <= width as usize, "{chars} > {width}: `{l}`");
                }
                // In a narrow terminal the label gives way to the figures.
                assert!(
                    width < 100 || lines.iter().any(|l| l.contains(&label[..18])),
                    "no label: {lines:?}"
                );
            }
        }
    }

    /// Characters on screen (without colour codes, which these templates do not use).
    fn console_width(s: &str) -> usize {
        s.chars().count()
    }
}
