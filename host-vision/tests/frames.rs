//! Frame sources on real files: small videos made by ffmpeg itself, image folders, and the
//! shared cube video when it is there. ffmpeg must be installed (`cargo xtask setup` does it).

use std::path::{Path, PathBuf};
use std::process::Command;

use frames::{Frame, FrameError, FrameInput, VideoOptions};

const HV: &str = env!("CARGO_BIN_EXE_host-vision");

fn tmp(name: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("frames")
        .join(name);
    let _ = std::fs::remove_dir_all(&p);
    let _ = std::fs::remove_file(&p);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    p
}

/// Makes a video of ffmpeg's test pattern; `extra` goes before the output name.
fn make_video(name: &str, size: &str, rate: u32, seconds: f64, extra: &[&str]) -> PathBuf {
    let out = tmp(name);
    let status = Command::new("ffmpeg")
        .args(["-v", "error", "-nostdin", "-f", "lavfi", "-i"])
        .arg(format!("testsrc=size={size}:rate={rate}"))
        .args(["-t", &seconds.to_string(), "-pix_fmt", "yuv420p"])
        .args(extra)
        .arg(&out)
        .status()
        .unwrap_or_else(|e| {
            panic!("ffmpeg is needed for these tests (`cargo xtask setup` installs it): {e}")
        });
    assert!(status.success(), "ffmpeg could not make {name}");
    out
}

fn read_all(input: &FrameInput) -> Result<Vec<Frame>, FrameError> {
    input.open(&VideoOptions::default())?.collect()
}

#[test]
fn a_small_video_gives_its_frames_sizes_and_container_times() {
    let video = make_video("tiny.mp4", "64x48", 10, 1.0, &[]);
    let frames = read_all(&FrameInput::Video(video.clone())).unwrap();
    assert_eq!(frames.len(), 10);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.index, i);
        assert_eq!(f.image.dimensions(), (64, 48));
        assert_eq!(f.t_ns, i as i64 * 100_000_000, "frame {i}");
    }
    // The test pattern is colourful: grey values spread, not a flat or empty frame.
    let px = frames[0].image.as_raw();
    let (lo, hi) = (px.iter().min().unwrap(), px.iter().max().unwrap());
    assert!(*lo < 60 && *hi > 200, "grey range {lo}..{hi}");

    // The container's times are kept: an mp4 whose stream starts at 5 s.
    let later = make_video("later.mp4", "32x24", 25, 0.4, &["-output_ts_offset", "5"]);
    let frames = read_all(&FrameInput::Video(later)).unwrap();
    assert_eq!(frames.len(), 10);
    let t: Vec<i64> = frames.iter().map(|f| f.t_ns).collect();
    assert_eq!(t[0], 5_000_000_000);
    assert_eq!(t[9], 5_360_000_000);

    // The frames subcommand reports the same.
    let out = Command::new(HV)
        .args(["frames", "--video"])
        .arg(&video)
        .args(["--intrinsics", "60,60,32,24"])
        .output()
        .unwrap();
    let so = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{so}");
    assert!(so.contains("frames:        10 of 64x48 px"), "{so}");
    assert!(so.contains("0.000000 s to 0.900000 s"), "{so}");
    assert!(so.contains("10.000 fps on average"), "{so}");
    assert!(so.contains("frames/s"), "{so}");
}

#[test]
fn bad_videos_and_a_missing_ffmpeg_are_named() {
    let err = |input: &FrameInput, options: &VideoOptions| match input
        .open(options)
        .and_then(|s| s.collect::<Result<Vec<_>, _>>())
    {
        Ok(v) => panic!("{} frames from a bad input", v.len()),
        Err(e) => e.to_string(),
    };
    let default = VideoOptions::default();
    let garbage = tmp("garbage.mp4");
    std::fs::write(&garbage, b"this is not a video").unwrap();
    let e = err(&FrameInput::Video(garbage.clone()), &default);
    assert!(
        e.starts_with(&format!("{}: ffmpeg cannot decode it", garbage.display()))
            && e.contains("Invalid data found when processing input"),
        "{e}"
    );
    // Half a file: ffmpeg's reason is passed on, whatever it is, and no frame is made up.
    let whole = std::fs::read(make_video("whole.mp4", "64x48", 10, 1.0, &[])).unwrap();
    let half = tmp("half.mp4");
    std::fs::write(&half, &whole[..whole.len() / 2]).unwrap();
    let e = err(&FrameInput::Video(half.clone()), &default);
    assert!(e.contains("ffmpeg cannot decode it"), "{e}");

    let e = err(&FrameInput::Video("/nonexistent/v.mp4".into()), &default);
    assert_eq!(e, "/nonexistent/v.mp4: no such file or folder");
    let missing = VideoOptions {
        ffmpeg: "/nonexistent/ffmpeg".into(),
    };
    let e = err(&FrameInput::Video(garbage.clone()), &missing);
    assert!(
        e.contains("`/nonexistent/ffmpeg` not found") && e.contains("cargo xtask setup"),
        "{e}"
    );
    // The command says it too, and fails (exit 1) without a panic.
    let out = Command::new(HV)
        .args(["frames", "--video"])
        .arg(&garbage)
        .env("PATH", "/nonexistent")
        .output()
        .unwrap();
    let se = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{se}");
    assert!(se.contains("`ffmpeg` not found"), "{se}");
}

fn write_png(path: &Path, w: u32, h: u32, seed: u8) {
    let img = image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x * 7) as u8 ^ seed, (y * 5) as u8, seed.wrapping_mul(3)])
    });
    img.save(path).unwrap();
}

#[test]
fn image_folders_in_name_order_at_fps_or_with_euroc_stamps() {
    let dir = tmp("folder");
    std::fs::create_dir_all(&dir).unwrap();
    // Written out of order: name order counts.
    for (name, seed) in [("f_002.png", 2), ("f_000.png", 0), ("f_001.png", 1)] {
        write_png(&dir.join(name), 20, 10, seed);
    }
    std::fs::write(dir.join("notes.txt"), "not a frame").unwrap();
    let input = FrameInput::Images {
        dir: dir.clone(),
        fps: Some(20.0),
    };
    let frames = read_all(&input).unwrap();
    assert_eq!(frames.len(), 3);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.t_ns, i as i64 * 50_000_000);
        // Grey as the dataset code makes it.
        let expected = image::open(dir.join(format!("f_00{i}.png")))
            .unwrap()
            .into_luma8();
        assert_eq!(f.image, expected, "frame {i}");
    }
    let e = read_all(&FrameInput::Images {
        dir: dir.clone(),
        fps: None,
    })
    .unwrap_err();
    assert!(
        e.to_string()
            .ends_with("a folder of 3 images without time stamps needs --fps")
    );
    let e = read_all(&FrameInput::Images {
        dir: dir.clone(),
        fps: Some(-1.0),
    })
    .unwrap_err();
    assert!(e.to_string().contains("--fps must be"), "{e}");

    // A wrongly sized frame and an unreadable one are named.
    write_png(&dir.join("f_003.png"), 10, 10, 3);
    let e = read_all(&input).unwrap_err().to_string();
    assert!(
        e.contains("f_003.png: frame 3 is 10x10 pixels, the first frame was 20x10"),
        "{e}"
    );
    std::fs::write(dir.join("f_003.png"), b"not a png").unwrap();
    let e = read_all(&input).unwrap_err().to_string();
    assert!(e.contains("f_003.png: frame 3: "), "{e}");

    let empty = tmp("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let e = read_all(&FrameInput::Images {
        dir: empty,
        fps: Some(10.0),
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("no frames (no .png, .jpg or .jpeg file"), "{e}");

    // A EuRoC cam0 folder: data.csv's stamps; --fps refused; stamps must increase.
    let cam0 = tmp("cam0");
    std::fs::create_dir_all(cam0.join("data")).unwrap();
    for (i, stamp) in [1000u64, 34_000_000, 67_000_000].iter().enumerate() {
        write_png(&cam0.join(format!("data/{stamp}.png")), 16, 8, i as u8);
    }
    let csv =
        "#timestamp [ns],filename\n1000,1000.png\n34000000,34000000.png\n67000000,67000000.png\n";
    std::fs::write(cam0.join("data.csv"), csv).unwrap();
    let input = FrameInput::Images {
        dir: cam0.clone(),
        fps: None,
    };
    let t: Vec<i64> = read_all(&input).unwrap().iter().map(|f| f.t_ns).collect();
    assert_eq!(t, [1000, 34_000_000, 67_000_000]);
    let e = read_all(&FrameInput::Images {
        dir: cam0.clone(),
        fps: Some(30.0),
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("give no --fps"), "{e}");
    std::fs::write(
        cam0.join("data.csv"),
        "1000,1000.png\n67000000,67000000.png\n34000000,34000000.png\n",
    )
    .unwrap();
    let e = read_all(&input).unwrap_err().to_string();
    assert!(e.contains("not increasing"), "{e}");
}

/// The shared cube video (../shared/data/visp-cube), when present: 989 frames of 640×480 at
/// 30 fps, its frame-0 intrinsics fitting.
#[test]
fn the_shared_cube_video_when_present() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/visp-cube");
    let video = dir.join("cube_video.mp4");
    if !video.exists() {
        eprintln!(
            "skipped: {} is not there (the shared data of issue 14)",
            video.display()
        );
        return;
    }
    let frames = read_all(&FrameInput::Video(video)).unwrap();
    assert_eq!(frames.len(), 989);
    assert!(frames.iter().all(|f| f.image.dimensions() == (640, 480)));
    for w in frames.windows(2) {
        let dt = w[1].t_ns - w[0].t_ns;
        assert!((dt - 33_333_333).abs() <= 1, "interval {dt} ns");
    }
    assert_eq!(frames[0].t_ns, 0);
    let camera = host_vision::camera::read_camera_json(&dir.join("camera.json")).unwrap();
    assert_eq!((camera.width, camera.height), (640, 480));
}

/// Issue 33, point 6: a cut-off file (or a pipe whose ffmpeg was killed) was read to its end
/// as if complete: ffmpeg exits 0 and says "File ended prematurely" only among its errors. The
/// frames before the cut are delivered, then the source fails, naming what ffmpeg said; the
/// `frames` command exits 1 with it. The whole file still reads cleanly.
#[test]
fn a_cut_off_video_ends_with_an_error_after_its_frames() {
    // The mp4 with its index first, so that the first half still has it.
    for (ext, extra) in [("mkv", &[][..]), ("mp4", &["-movflags", "+faststart"][..])] {
        let whole = make_video(&format!("cut-whole.{ext}"), "160x120", 30, 3.0, extra);
        assert_eq!(
            read_all(&FrameInput::Video(whole.clone())).unwrap().len(),
            90
        );
        let bytes = std::fs::read(&whole).unwrap();
        let half = tmp(&format!("cut-half.{ext}"));
        std::fs::write(&half, &bytes[..bytes.len() / 2]).unwrap();
        let frames: Vec<Result<Frame, FrameError>> = FrameInput::Video(half.clone())
            .open(&VideoOptions::default())
            .unwrap()
            .collect();
        let (last, good) = frames.split_last().unwrap();
        assert!(good.iter().all(Result::is_ok), "{ext}");
        match last {
            Err(FrameError::EndedAbnormally { frames, reason, .. }) => {
                assert_eq!(*frames, good.len(), "{ext}");
                assert!(!reason.is_empty(), "{ext}");
            }
            // A cut inside the first frames may fail the decode outright.
            other => panic!("{ext}: {other:?}"),
        }
        let out = Command::new(HV)
            .args(["frames", "--video"])
            .arg(&half)
            .output()
            .unwrap();
        let se = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{ext}: {se}");
        assert!(
            se.contains("the stream ended abnormally after"),
            "{ext}: {se}"
        );
    }
}
