//! What ffmpeg says on stderr at `-loglevel level+info` with the `showinfo` filter, read line by
//! line: the filter's time base, one line per frame (its number, integer `pts` and size), and
//! ffmpeg's error lines.
//!
//! The integer `pts` times the time base gives exact frame times; `pts_time` is printed with
//! six significant digits only, too coarse for a camera's clock (seconds since boot).

/// One line of ffmpeg's stderr, as far as the frame source cares.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Line {
    /// `config in time_base: NUM/DEN, frame_rate: N/D` of the showinfo filter.
    Config {
        /// Time base of the frames' `pts` [s] as `(num, den)`.
        time_base: (i64, i64),
        /// Stream frame rate `(num, den)`; `(0, 0)` or `(0, 1)` when unknown.
        frame_rate: (i64, i64),
    },
    /// `n: N pts: P ... s:WxH ...`: a frame on its way to the pipe.
    Frame {
        /// Frame number, from 0.
        n: usize,
        /// Presentation time in time-base units; `None` for `NOPTS`.
        pts: Option<i64>,
        /// Width and height.
        size: (u32, u32),
    },
    /// An error or fatal message (its text without the context and level tags).
    Error(String),
    /// Anything else.
    Other,
}

/// Splits `[ctx @ 0x..] [level] text` into (context, level, text).
fn split_tags(line: &str) -> (Option<&str>, Option<&str>, &str) {
    let mut rest = line.trim_end();
    let mut context = None;
    let mut level = None;
    while let Some(tail) = rest.strip_prefix('[') {
        let Some(end) = tail.find("] ") else { break };
        let tag = &tail[..end];
        if tag.contains(" @ ") {
            context = Some(tag);
        } else if matches!(
            tag,
            "quiet"
                | "panic"
                | "fatal"
                | "error"
                | "warning"
                | "info"
                | "verbose"
                | "debug"
                | "trace"
        ) {
            level = Some(tag);
        } else {
            break;
        }
        rest = &tail[end + 2..];
    }
    // A level tag with nothing after it ends in "]" without the space.
    if level.is_none()
        && let Some(tag) = rest.strip_prefix('[').and_then(|t| t.strip_suffix(']'))
        && matches!(tag, "error" | "fatal" | "info" | "warning")
    {
        return (context, Some(tag), "");
    }
    (context, level, rest)
}

/// `key:` followed by a value (spaces after the colon allowed), as showinfo prints it.
fn field<'a>(text: &'a str, key: &str) -> Option<&'a str> {
    let mut from = 0;
    while let Some(at) = text[from..].find(key) {
        let start = from + at;
        let boundary = start == 0 || text.as_bytes()[start - 1] == b' ';
        let after = &text[start + key.len()..];
        if boundary && let Some(v) = after.strip_prefix(':') {
            return v.split_whitespace().next();
        }
        from = start + key.len();
    }
    None
}

fn ratio(s: &str) -> Option<(i64, i64)> {
    let (a, b) = s.trim_end_matches(',').split_once('/')?;
    Some((a.parse().ok()?, b.parse().ok()?))
}

/// Reads one stderr line.
pub fn parse(line: &str) -> Line {
    let (context, level, text) = split_tags(line);
    if matches!(level, Some("error" | "fatal" | "panic")) {
        return Line::Error(text.to_owned());
    }
    if !context.is_some_and(|c| c.contains("showinfo")) {
        return Line::Other;
    }
    if let Some(cfg) = text.strip_prefix("config in ") {
        if let (Some(tb), Some(fr)) = (field(cfg, "time_base"), field(cfg, "frame_rate"))
            && let (Some(time_base), Some(frame_rate)) = (ratio(tb), ratio(fr))
        {
            return Line::Config {
                time_base,
                frame_rate,
            };
        }
        return Line::Other;
    }
    if !text.starts_with("n:") {
        return Line::Other;
    }
    let n = field(text, "n").and_then(|v| v.parse().ok());
    let pts = field(text, "pts");
    let size = field(text, "s").and_then(|s| {
        let (w, h) = s.split_once('x')?;
        Some((w.parse().ok()?, h.parse().ok()?))
    });
    match (n, pts, size) {
        (Some(n), Some(pts), Some(size)) => Line::Frame {
            n,
            pts: pts.parse().ok(),
            size,
        },
        _ => Line::Other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    // Lines as ffmpeg 5.1 prints them.
    const FRAME: &str = "[Parsed_showinfo_1 @ 0x55f1579ef940] [info] n:   0 pts:      0 pts_time:0       pos:       48 fmt:gray sar:1/1 s:64x48 i:P iskey:1 type:I checksum:78F3DDE1 plane_checksum:[78F3DDE1] mean:[125] stdev:[81.0]";

    #[test]
    fn frame_lines_give_number_pts_and_size() {
        assert_eq!(
            parse(FRAME),
            Line::Frame {
                n: 0,
                pts: Some(0),
                size: (64, 48)
            }
        );
        let later = "[Parsed_showinfo_1 @ 0x1] [info] n: 988 pts: 505856 pts_time:32.9333 duration:512 fmt:gray s:640x480 i:P";
        assert_eq!(
            parse(later),
            Line::Frame {
                n: 988,
                pts: Some(505856),
                size: (640, 480)
            }
        );
        let nopts = "[Parsed_showinfo_1 @ 0x1] [info] n:   3 pts:NOPTS pts_time:NOPTS s:64x48";
        assert_eq!(
            parse(nopts),
            Line::Frame {
                n: 3,
                pts: None,
                size: (64, 48)
            }
        );
    }

    #[test]
    fn config_errors_and_other_lines() {
        assert_eq!(
            parse(
                "[Parsed_showinfo_1 @ 0x55f1579ef940] [info] config in time_base: 1/10240, frame_rate: 10/1"
            ),
            Line::Config {
                time_base: (1, 10240),
                frame_rate: (10, 1)
            }
        );
        assert_eq!(
            parse("[Parsed_showinfo_1 @ 0x5] [info] config out time_base: 0/0, frame_rate: 0/0"),
            Line::Other
        );
        assert_eq!(
            parse("[error] /tmp/bad.mp4: Invalid data found when processing input"),
            Line::Error("/tmp/bad.mp4: Invalid data found when processing input".into())
        );
        assert_eq!(
            parse("[mov,mp4,m4a,3gp,3g2,mj2 @ 0x55f60b42d900] [error] moov atom not found"),
            Line::Error("moov atom not found".into())
        );
        // Side data of showinfo and ffmpeg's own info lines are not frames.
        assert_eq!(
            parse("[Parsed_showinfo_1 @ 0x5] [info] color_range:pc color_space:unknown"),
            Line::Other
        );
        assert_eq!(
            parse("[info]   Stream #0:0 -> #0:0 (h264 (native) -> rawvideo (native))"),
            Line::Other
        );
        assert_eq!(
            parse("[info] n:   0 pts: 0 s:64x48 (not from showinfo)"),
            Line::Other
        );
    }

    proptest! {
        /// Arbitrary text, and showinfo's frame line with characters replaced at random: a
        /// line read or not, never a panic (ffmpeg's stderr carries what the file makes it
        /// print, file names and tags included).
        #[test]
        fn any_line_reads_without_panicking(line in any::<String>()) {
            let _ = parse(&line);
        }

        #[test]
        fn mutated_frame_lines_read_without_panicking(
            edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<char>()), 1..8),
        ) {
            let mut chars: Vec<char> = FRAME.chars().collect();
            for (at, c) in edits {
                let i = at.index(chars.len());
                chars[i] = c;
            }
            let line: String = chars.into_iter().collect();
            let _ = parse(&line);
        }

        /// Every frame number, time stamp and size comes back as printed.
        #[test]
        fn frame_fields_round_trip(n in any::<usize>(), pts in any::<i64>(), w in any::<u32>(), h in any::<u32>()) {
            let line = format!("[Parsed_showinfo_1 @ 0x1] [info] n:{n:4} pts:{pts:7} pts_time:0 s:{w}x{h} i:P");
            prop_assert_eq!(parse(&line), Line::Frame { n, pts: Some(pts), size: (w, h) });
        }
    }
}
