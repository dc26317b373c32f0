//! Faults the application injects into a run, for tests of the tracker's and the core's
//! robustness: outliers among the correspondences and a pulled cable (a wrapper around the
//! link, [`FaultyLink`]), frames replaced by noise (a frame filter, [`Faults::noise_frame`]),
//! and the core reset or the cable pulled at a given time ([`Injector`]). The line's bit
//! errors and the reset line are the link's own ([`CoreLink`]).

use std::time::Duration;

use core_link::CoreLink;
use nalgebra::Vector3;
use protocol::{Correspondence, HostToCore};
use rand::rngs::StdRng;
use rand::{RngExt as _, SeedableRng};
use tracker::{CoreTransport, Incoming, Tracker, TrackerError};

/// Faults injected by the host, for tests of the core's robustness.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Faults {
    /// Fraction of correspondences replaced by outliers (model point moved 0.1-0.5 m).
    pub outlier_fraction: f64,
    /// From this time [s] on, for `corrupt_seconds`, every correspondence is an outlier:
    /// the core's divergence monitor must fire and tracking must resume.
    pub corrupt_from: Option<f64>,
    /// Length of the corrupted stretch [s].
    pub corrupt_seconds: f64,
    /// From this time [s] on, for `blind_seconds`, every frame is replaced by noise: the model
    /// is gone from the images (a covered lens, garbage frames) while the camera moves. The
    /// core dead-reckons; the model must be found again once the frames are back.
    pub blind_from: Option<f64>,
    /// Length of the blind stretch [s].
    pub blind_seconds: f64,
    /// Bit errors on the line to the simulated board: the probability that a byte has a bit
    /// flipped, in both directions. Damaged frames must be detected and dropped at both ends.
    pub line_errors: Option<f64>,
    /// At this time [s] the core is reset (the simulated board's reset line, or QEMU killed):
    /// the host must notice, configure and initialise it again, and resume.
    pub reset_core_at: Option<f64>,
    /// At this time [s] the cable is pulled: the host's end of the line is closed, and
    /// reconnecting fails for `cut_seconds`.
    pub cut_link_at: Option<f64>,
    /// How long the cable stays out [s].
    pub cut_seconds: f64,
    /// Seed of the injected faults.
    pub seed: u64,
}

impl Faults {
    /// Whether the frame at `t` [s] is replaced by noise.
    pub fn blind_at(&self, t: f64) -> bool {
        self.blind_from
            .is_some_and(|from| t >= from && t < from + self.blind_seconds)
    }

    /// The noise that replaces frame `index` of a blind stretch (uniform grey levels, the same
    /// in every run of a seed).
    pub fn noise_frame(&self, width: u32, height: u32, index: usize) -> image::GrayImage {
        let mut rng = StdRng::seed_from_u64(self.seed ^ (index as u64).wrapping_mul(0x9E37_79B9));
        image::GrayImage::from_fn(width, height, |_, _| image::Luma([rng.random::<u8>()]))
    }
}

/// Replaces a correspondence's model point by one 0.1-0.5 m away in a random direction.
fn outlier(c: &mut Correspondence, rng: &mut StdRng) {
    let dir = Vector3::new(
        rng.random::<f64>() - 0.5,
        rng.random::<f64>() - 0.5,
        rng.random::<f64>() - 0.5,
    )
    .try_normalize(1e-9)
    .unwrap_or_else(Vector3::x);
    let shift = dir * (0.1 + 0.4 * rng.random::<f64>());
    for (m, s) in c.m_w.iter_mut().zip(shift.iter()) {
        *m += *s as f32;
    }
}

/// The link to the core with correspondences replaced by outliers on the way: a fraction of
/// them at random (`--outliers`), and all of them in a stretch (`--corrupt-at`). Everything
/// else of [`CoreLink`] is reached through it.
pub struct FaultyLink {
    link: CoreLink,
    faults: Faults,
    rng: StdRng,
    /// Correspondences replaced by outliers.
    pub injected: usize,
    /// The input's time now [µs], and until when the cable is out.
    now_us: u64,
    unplugged_until_us: Option<u64>,
}

impl FaultyLink {
    /// `link` with `faults`' outliers injected.
    pub fn new(link: CoreLink, faults: &Faults) -> Self {
        Self {
            link,
            faults: *faults,
            rng: StdRng::seed_from_u64(faults.seed),
            injected: 0,
            now_us: 0,
            unplugged_until_us: None,
        }
    }

    /// Pulls the cable until `until_us` of the input's time: the host's end is closed, and
    /// reconnecting fails until then, as a serial adaptor that is gone does.
    pub fn unplug(&mut self, until_us: u64) {
        self.link.cut();
        self.unplugged_until_us = Some(until_us);
    }

    /// The link itself.
    pub fn into_inner(self) -> CoreLink {
        self.link
    }

    /// The link itself, to feed the in-process board's simulated IMU.
    pub fn link_mut(&mut self) -> &mut CoreLink {
        &mut self.link
    }

    /// Sends `msg`, a frame's correspondences with the faults' outliers among them.
    pub fn send(&mut self, msg: &HostToCore) -> Result<(), TrackerError> {
        let f = &self.faults;
        let HostToCore::Correspondences(part) = msg else {
            return self.link.send(msg);
        };
        let t = part.trigger_us as f64 * 1e-6;
        let corrupt = f
            .corrupt_from
            .is_some_and(|from| t >= from && t < from + f.corrupt_seconds);
        if !corrupt && f.outlier_fraction <= 0.0 {
            return self.link.send(msg);
        }
        let mut part = part.clone();
        for c in &mut part.items {
            if corrupt
                || (f.outlier_fraction > 0.0 && self.rng.random::<f64>() < f.outlier_fraction)
            {
                self.injected += 1;
                outlier(c, &mut self.rng);
            }
        }
        self.link.send(&HostToCore::Correspondences(part))
    }
}

impl std::ops::Deref for FaultyLink {
    type Target = CoreLink;

    fn deref(&self) -> &CoreLink {
        &self.link
    }
}

impl std::ops::DerefMut for FaultyLink {
    fn deref_mut(&mut self) -> &mut CoreLink {
        &mut self.link
    }
}

impl CoreTransport for FaultyLink {
    fn name(&self) -> &str {
        self.link.name()
    }

    fn send(&mut self, msg: &HostToCore) -> Result<(), TrackerError> {
        FaultyLink::send(self, msg)
    }

    fn recv_within(&mut self, timeout: Duration) -> Result<Option<Incoming>, TrackerError> {
        self.link.recv_within(timeout)
    }

    fn try_recv(&mut self) -> Result<Option<Incoming>, TrackerError> {
        self.link.try_recv()
    }

    fn reconnect(&mut self) -> Result<(), TrackerError> {
        if self
            .unplugged_until_us
            .is_some_and(|until| self.now_us < until)
        {
            return Err(TrackerError::Link("the cable is out (injected)".into()));
        }
        self.link.reconnect()
    }

    fn lossy(&self) -> bool {
        self.link.damage.is_some()
    }

    fn is_connected(&self) -> bool {
        self.link.is_connected()
    }

    fn disconnect(&mut self) {
        self.link.cut();
    }
}

/// The core reset and the cable pulled at their times (`--reset-core-at`, `--cut-link-at`),
/// once each, while the core is there.
#[derive(Debug, Default)]
pub struct Injector {
    reset_done: bool,
    cut_done: bool,
}

impl Injector {
    /// Injects what is due at the sample of time `t_us` into `tracker`'s link.
    pub fn inject(
        &mut self,
        faults: &Faults,
        tracker: &mut Tracker<FaultyLink>,
        t_us: u64,
    ) -> Result<(), TrackerError> {
        tracker.core_mut().now_us = t_us;
        if tracker.in_outage() {
            return Ok(());
        }
        let t = t_us as f64 * 1e-6;
        if let Some(at) = faults
            .reset_core_at
            .filter(|&at| t >= at && !self.reset_done)
        {
            self.reset_done = true;
            tracker.inject(at, |link| link.reset_core())?;
        }
        if let Some(at) = faults.cut_link_at.filter(|&at| t >= at && !self.cut_done) {
            self.cut_done = true;
            let until = t_us + (faults.cut_seconds.max(0.0) * 1e6) as u64;
            tracker.inject(at, |link| {
                link.unplug(until);
                Ok(())
            })?;
        }
        Ok(())
    }
}
