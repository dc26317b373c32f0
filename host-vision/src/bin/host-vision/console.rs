//! What the program says on its terminal, and how it exits.

use std::process::ExitCode;

/// Prints a line on stdout. A closed stdout (`host-vision track … | head -1`) is no reason to
/// panic or to stop: the run's files are its product.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}
pub(crate) use say;

/// Prints a line on stderr, ignoring a closed stderr as [`say`] does stdout.
macro_rules! note {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}
pub(crate) use note;

/// Exit codes (listed in the top-level `--help`).
pub mod exit {
    /// Failed: input, link or output.
    pub const FAILED: u8 = 1;
    /// Bad command line or option value.
    pub const USAGE: u8 = 2;
    /// Ran, but found nothing: `track`'s core accepted no correspondence (tracking never
    /// started), or `locate` found no pose.
    pub const NEVER_TRACKED: u8 = 3;
    /// Interrupted (Ctrl-C), the shell's convention (128 + SIGINT).
    pub const INTERRUPTED: u8 = 130;
}

/// A failure and the code to exit with.
#[derive(Debug)]
pub struct Failure {
    /// The error.
    pub error: anyhow::Error,
    /// Exit code.
    pub code: u8,
}

impl<E: Into<anyhow::Error>> From<E> for Failure {
    fn from(e: E) -> Self {
        let error = e.into();
        let code = classify(&error);
        Failure { error, code }
    }
}

/// Bad options are usage errors; an interruption before anything was tracked is one too.
fn classify(error: &anyhow::Error) -> u8 {
    use host_vision::eval::EvalError;
    use host_vision::track::TrackError;
    let track = error.chain().find_map(|e| e.downcast_ref::<TrackError>());
    let eval_option = matches!(
        error.downcast_ref::<EvalError>(),
        Some(EvalError::Option(_))
    );
    // A frame of another size than the camera given is the options' disagreement, as `track`
    // says it.
    let locate_size = error.chain().any(|e| {
        matches!(
            e.downcast_ref::<host_vision::locate::run::LocateError>(),
            Some(host_vision::locate::run::LocateError::ImageSize { .. })
        )
    });
    match track {
        Some(TrackError::Option(_)) => exit::USAGE,
        _ if locate_size => exit::USAGE,
        _ if eval_option => exit::USAGE,
        Some(TrackError::Interrupted) => exit::INTERRUPTED,
        _ if matches!(
            error.downcast_ref::<EvalError>(),
            Some(EvalError::Synth { source, .. })
                if matches!(**source, host_vision::synth::SynthError::Interrupted)
        ) =>
        {
            exit::INTERRUPTED
        }
        _ => exit::FAILED,
    }
}

/// The error and its causes on one line, each cause once: our errors often quote their cause
/// in their own message already ("…: No such file or directory").
pub fn message(error: &anyhow::Error) -> String {
    let mut text = error.to_string();
    for cause in error.chain().skip(1) {
        let c = cause.to_string();
        if !text.contains(&c) {
            text.push_str(": ");
            text.push_str(&c);
        }
    }
    text
}

/// Reports `failure` on stderr and returns its exit code.
pub fn report(failure: Failure) -> ExitCode {
    note!("Error: {}", message(&failure.error));
    ExitCode::from(failure.code)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("cannot open x: {source}")]
    struct Quoting {
        #[source]
        source: std::io::Error,
    }

    #[test]
    fn each_cause_is_said_once() {
        let e = anyhow::Error::from(Quoting {
            source: std::io::Error::other("No such file"),
        })
        .context("tracking");
        assert_eq!(message(&e), "tracking: cannot open x: No such file");
        let e = anyhow::anyhow!("inner").context("outer");
        assert_eq!(message(&e), "outer: inner");
    }

    #[test]
    fn bad_options_are_usage_errors() {
        let f = Failure::from(host_vision::track::TrackError::Option("--features".into()));
        assert_eq!(f.code, exit::USAGE);
        let f = Failure::from(anyhow::anyhow!("other"));
        assert_eq!(f.code, exit::FAILED);
    }
}
