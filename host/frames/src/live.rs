//! Live frames: a capture thread that always holds only the **newest** frame of a source, so
//! that a tracker slower than its camera analyses the frame the user sees now and never a
//! queue of old ones (docs/ARCHITECTURE.md, "Live tracking"). Frames replaced before they were
//! taken are counted as dropped, never queued. [`Paced`] plays a recorded source at its own
//! frame rate, as a camera would deliver it, so that a live run can be reproduced without a
//! camera.

use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tracker::Frame;

/// A frame as the capture thread took it from its source.
#[derive(Debug)]
pub struct Captured {
    /// The frame, its `captured` instant set to when the source delivered it.
    pub frame: Frame,
    /// Frames the source delivered since the last one taken, replaced before anyone took
    /// them.
    pub dropped: usize,
    /// Frames the source had delivered when this one was taken, this one included: it was
    /// the newest, so no other waited behind it.
    pub delivered: usize,
}

/// The newest frame, and how the source ended.
struct Slot<E> {
    newest: Option<Frame>,
    /// Frames replaced in the slot since the last [`LiveFrames::next`].
    dropped: usize,
    /// Frames the source delivered.
    delivered: usize,
    /// The source ended: `Ok` at its end, `Err` with what it said.
    ended: Option<Result<(), E>>,
    /// The reader went away: the capture thread stops.
    closed: bool,
}

/// Counts of a live source.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LiveCounts {
    /// Frames the source delivered.
    pub delivered: usize,
    /// Frames taken by the reader.
    pub taken: usize,
    /// Frames replaced before they were taken.
    pub dropped: usize,
}

/// A source read on a capture thread of its own, of which only the newest frame is kept.
pub struct LiveFrames<E> {
    shared: Arc<(Mutex<Slot<E>>, Condvar)>,
    handle: Option<JoinHandle<()>>,
    counts: LiveCounts,
}

impl<E: Send + 'static> LiveFrames<E> {
    /// Starts the capture thread on `source`, an iterator of frames that ends at its first
    /// error (a camera that stopped, a pipe closed). The frames' `captured` instants are set
    /// when they come out of the source (where it set none).
    pub fn start<I>(source: I) -> Result<Self, std::io::Error>
    where
        I: Iterator<Item = Result<Frame, E>> + Send + 'static,
    {
        let shared = Arc::new((
            Mutex::new(Slot {
                newest: None,
                dropped: 0,
                delivered: 0,
                ended: None,
                closed: false,
            }),
            Condvar::new(),
        ));
        let inner = shared.clone();
        let handle = std::thread::Builder::new()
            .name("capture".into())
            .spawn(move || capture(source, &inner))?;
        Ok(Self {
            shared,
            handle: Some(handle),
            counts: LiveCounts::default(),
        })
    }

    /// The newest frame, waiting for one if none has come since the last; `None` once the
    /// source has ended and its last frame was taken, `Some(Err)` with what the source said
    /// where it ended on an error.
    pub fn next_frame(&mut self) -> Option<Result<Captured, E>> {
        let (lock, ready) = &*self.shared;
        let mut slot = lock.lock().unwrap_or_else(PoisonError::into_inner);
        loop {
            if let Some(frame) = slot.newest.take() {
                let dropped = std::mem::take(&mut slot.dropped);
                self.counts.taken += 1;
                self.counts.dropped += dropped;
                self.counts.delivered = slot.delivered;
                return Some(Ok(Captured {
                    frame,
                    dropped,
                    delivered: slot.delivered,
                }));
            }
            if let Some(end) = slot.ended.take() {
                self.counts.delivered = slot.delivered;
                // Told once; after it, the source is over.
                slot.ended = Some(Ok(()));
                return end.err().map(Err);
            }
            slot = ready.wait(slot).unwrap_or_else(PoisonError::into_inner);
        }
    }

    /// The counts so far.
    pub fn counts(&self) -> LiveCounts {
        self.counts
    }
}

impl<E: Send + 'static> Iterator for LiveFrames<E> {
    type Item = Result<Captured, E>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_frame()
    }
}

impl<E> Drop for LiveFrames<E> {
    fn drop(&mut self) {
        let (lock, _) = &*self.shared;
        lock.lock().unwrap_or_else(PoisonError::into_inner).closed = true;
        // A capture thread blocked in its source (a camera's read) ends at its next frame;
        // it is not waited for.
        if let Some(h) = self.handle.take()
            && h.is_finished()
        {
            let _ = h.join();
        }
    }
}

/// The capture thread: each frame replaces the one before in the slot.
fn capture<I, E>(source: I, shared: &(Mutex<Slot<E>>, Condvar))
where
    I: Iterator<Item = Result<Frame, E>>,
{
    let (lock, ready) = shared;
    for item in source {
        let mut slot = lock.lock().unwrap_or_else(PoisonError::into_inner);
        if slot.closed {
            return;
        }
        match item {
            Ok(mut frame) => {
                frame.captured.get_or_insert_with(Instant::now);
                slot.delivered += 1;
                if slot.newest.replace(frame).is_some() {
                    slot.dropped += 1;
                }
            }
            Err(e) => {
                slot.ended = Some(Err(e));
                ready.notify_all();
                return;
            }
        }
        ready.notify_all();
    }
    let mut slot = lock.lock().unwrap_or_else(PoisonError::into_inner);
    slot.ended.get_or_insert(Ok(()));
    ready.notify_all();
}

/// A recorded source played at its own frame rate: each frame comes out when the wall clock
/// since the first reaches its time stamp since the first, as a camera would deliver it.
/// Its `captured` instant is that moment.
pub struct Paced<I> {
    inner: I,
    /// The first frame's stamp [ns] and wall-clock instant.
    origin: Option<(i64, Instant)>,
}

impl<I> Paced<I> {
    /// Plays `inner` in real time.
    pub fn new(inner: I) -> Self {
        Self {
            inner,
            origin: None,
        }
    }
}

impl<I, E> Iterator for Paced<I>
where
    I: Iterator<Item = Result<Frame, E>>,
{
    type Item = Result<Frame, E>;

    fn next(&mut self) -> Option<Self::Item> {
        let mut item = self.inner.next()?;
        if let Ok(frame) = &mut item {
            let (t0, start) = *self.origin.get_or_insert((frame.t_ns, Instant::now()));
            let since = u64::try_from(frame.t_ns.saturating_sub(t0)).unwrap_or(0);
            let due = start + Duration::from_nanos(since);
            if let Some(wait) = due.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
            // Captured when it comes out: at its time, or later where the decoder fell
            // behind (then that lateness is part of the frame's age, as a camera's would be).
            frame.captured = Some(Instant::now());
        }
        Some(item)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::GrayImage;

    fn frames(n: usize, period_ms: i64) -> Vec<Result<Frame, String>> {
        (0..n)
            .map(|i| {
                Ok(Frame::decoded(
                    i,
                    i as i64 * period_ms * 1_000_000,
                    GrayImage::new(4, 4),
                ))
            })
            .collect()
    }

    #[test]
    fn a_slow_reader_gets_the_newest_frame_and_the_rest_are_counted_dropped() {
        let mut live = LiveFrames::start(Paced::new(frames(20, 5).into_iter())).unwrap();
        let mut taken = Vec::new();
        while let Some(c) = live.next_frame() {
            let c = c.unwrap();
            assert_eq!(c.frame.index + 1, c.delivered, "the newest frame");
            taken.push((c.frame.index, c.dropped));
            std::thread::sleep(Duration::from_millis(18));
        }
        let counts = live.counts();
        assert_eq!(counts.delivered, 20);
        assert_eq!(counts.taken, taken.len());
        assert_eq!(counts.taken + counts.dropped, 20, "{taken:?}");
        assert!(counts.dropped >= 10, "{taken:?}");
        // Each frame's drops are the frames between it and the one taken before.
        let mut last: Option<usize> = None;
        for &(index, dropped) in &taken {
            assert_eq!(index - last.map_or(0, |l| l + 1), dropped, "{taken:?}");
            last = Some(index);
        }
        assert_eq!(last, Some(19), "the last frame is always taken");
    }

    #[test]
    fn a_source_error_ends_the_stream_after_the_frames_before_it() {
        let mut items = frames(3, 1);
        items.push(Err("the pipe closed".into()));
        let mut live = LiveFrames::start(items.into_iter()).unwrap();
        let mut got = Vec::new();
        let end = loop {
            match live.next_frame() {
                Some(Ok(c)) => got.push(c.frame.index),
                Some(Err(e)) => break e,
                None => panic!("the error is told"),
            }
        };
        assert_eq!(end, "the pipe closed");
        assert_eq!(got.last(), Some(&2));
        assert!(live.next_frame().is_none());
    }

    #[test]
    fn paced_frames_come_out_at_their_stamps() {
        let start = Instant::now();
        let out: Vec<_> = Paced::new(frames(4, 20).into_iter())
            .map(|f| f.unwrap().captured.unwrap() - start)
            .collect();
        assert!(out[3] >= Duration::from_millis(60), "{out:?}");
        for w in out.windows(2) {
            assert!(w[1] > w[0]);
        }
    }
}
