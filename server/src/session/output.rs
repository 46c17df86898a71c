//! What a session sends to its viewer (DESIGN.md "Frames to the viewer"): frames are
//! latest-frame-wins — the frame loop never waits for a slow link, a newer frame replaces one
//! the viewer has not taken yet (counted as dropped) — while `Rejected` notices are queued
//! and never replaced, since each answers one viewer message. Progress of long work is
//! latest-wins per stage (the viewer wants the state of the work, not its history).
use edgepoint_proto::{server_msg, Frame, Picked, Progress, Rejected, ServerMsg};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;
use tokio::sync::Notify;

/// Rejections kept waiting for the viewer; beyond this the oldest are discarded (a viewer
/// flooding bad messages must not grow the server's memory).
pub const MAX_QUEUED_REJECTIONS: usize = 256;

#[derive(Default)]
struct Slots {
    frame: Option<Frame>,
    rejected: VecDeque<Rejected>,
    /// Answers to picks, queued like rejections (each answers one viewer message).
    picked: VecDeque<Picked>,
    /// The newest progress of each stage not yet taken, in the order the stages began.
    progress: Vec<Progress>,
    ended: bool,
}

/// The hand-over point between the frame-loop thread and the async stream to the viewer.
pub struct SessionOutput {
    slots: Mutex<Slots>,
    notify: Notify,
    frames_dropped: AtomicU64,
    frames_published: AtomicU64,
    closed: AtomicBool,
    /// Becomes true once the session ended or was closed, for tasks that must stop with it.
    done: tokio::sync::watch::Sender<bool>,
}

impl Default for SessionOutput {
    fn default() -> Self {
        SessionOutput {
            slots: Mutex::default(),
            notify: Notify::new(),
            frames_dropped: AtomicU64::new(0),
            frames_published: AtomicU64::new(0),
            closed: AtomicBool::new(false),
            done: tokio::sync::watch::Sender::new(false),
        }
    }
}

impl SessionOutput {
    pub fn new() -> Self {
        Self::default()
    }

    /// Resolves once the session has ended or been closed.
    pub async fn done(&self) {
        let mut rx = self.done.subscribe();
        // The sender lives in `self`, so this cannot fail while we borrow it.
        let _ = rx.wait_for(|d| *d).await;
    }

    fn slots(&self) -> std::sync::MutexGuard<'_, Slots> {
        self.slots.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Offers the newest frame; a frame still waiting is replaced and counted as dropped.
    pub fn publish_frame(&self, frame: Frame) {
        let replaced = self.slots().frame.replace(frame).is_some();
        if replaced {
            self.frames_dropped.fetch_add(1, Ordering::Relaxed);
        }
        self.frames_published.fetch_add(1, Ordering::Relaxed);
        self.notify.notify_one();
    }

    /// Queues a rejection notice for the viewer.
    pub fn reject(&self, code: tonic::Code, message: impl Into<String>) {
        {
            let mut s = self.slots();
            if s.rejected.len() >= MAX_QUEUED_REJECTIONS {
                s.rejected.pop_front();
            }
            s.rejected.push_back(Rejected { code: code as i32, message: message.into() });
        }
        self.notify.notify_one();
    }

    /// Queues the answer to a pick (bounded like rejections).
    pub fn picked(&self, p: Picked) {
        {
            let mut s = self.slots();
            if s.picked.len() >= MAX_QUEUED_REJECTIONS {
                s.picked.pop_front();
            }
            s.picked.push_back(p);
        }
        self.notify.notify_one();
    }

    /// Offers the newest state of a stage of the session's long work; an untaken one of
    /// the same stage is replaced.
    pub fn progress(&self, p: Progress) {
        {
            let mut s = self.slots();
            match s.progress.iter_mut().find(|q| q.stage == p.stage) {
                Some(q) => *q = p,
                None => s.progress.push(p),
            }
        }
        self.notify.notify_one();
    }

    /// The frame loop has ended: once the queued messages are taken, [`Self::next`] ends.
    pub fn end(&self) {
        self.slots().ended = true;
        self.done.send_replace(true);
        self.notify.notify_one();
    }

    /// Frames replaced before the viewer took them.
    pub fn frames_dropped(&self) -> u64 {
        self.frames_dropped.load(Ordering::Relaxed)
    }

    pub fn frames_published(&self) -> u64 {
        self.frames_published.load(Ordering::Relaxed)
    }

    /// The viewer is gone: the frame loop stops at its next check.
    pub fn close(&self) {
        self.closed.store(true, Ordering::SeqCst);
        self.done.send_replace(true);
        self.notify.notify_one();
    }

    pub fn is_closed(&self) -> bool {
        self.closed.load(Ordering::SeqCst)
    }

    /// Takes what is ready without waiting: rejections first, then pick answers, progress,
    /// then the newest frame.
    pub fn try_next(&self) -> Option<ServerMsg> {
        let mut s = self.slots();
        if let Some(r) = s.rejected.pop_front() {
            return Some(ServerMsg { msg: Some(server_msg::Msg::Rejected(r)) });
        }
        if let Some(p) = s.picked.pop_front() {
            return Some(ServerMsg { msg: Some(server_msg::Msg::Picked(p)) });
        }
        if !s.progress.is_empty() {
            return Some(ServerMsg { msg: Some(server_msg::Msg::Progress(s.progress.remove(0))) });
        }
        s.frame.take().map(|f| ServerMsg { msg: Some(server_msg::Msg::Frame(f)) })
    }

    /// Waits for the next message for the viewer; `None` once the session ended (or was
    /// closed) and everything queued was taken.
    pub async fn next(&self) -> Option<ServerMsg> {
        loop {
            if let Some(m) = self.try_next() {
                return Some(m);
            }
            if self.slots().ended || self.is_closed() {
                return None;
            }
            // `notify_one` stores a permit when nobody waits, so a publish between the
            // check above and this await is not lost.
            self.notify.notified().await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(seq: u64) -> Frame {
        Frame { sequence: seq, ..Default::default() }
    }

    fn seq_of(m: ServerMsg) -> u64 {
        match m.msg {
            Some(server_msg::Msg::Frame(f)) => f.sequence,
            other => panic!("expected a frame, got {other:?}"),
        }
    }

    #[test]
    fn newest_frame_wins_and_drops_are_counted() {
        let out = SessionOutput::new();
        out.publish_frame(frame(1));
        out.publish_frame(frame(2));
        out.publish_frame(frame(3));
        assert_eq!(out.frames_dropped(), 2);
        assert_eq!(seq_of(out.try_next().unwrap()), 3);
        assert!(out.try_next().is_none());
        out.publish_frame(frame(4));
        assert_eq!(seq_of(out.try_next().unwrap()), 4);
        assert_eq!(out.frames_dropped(), 2, "a taken frame is not a drop");
        assert_eq!(out.frames_published(), 4);
    }

    #[test]
    fn rejections_queue_ahead_of_frames_and_are_bounded() {
        let out = SessionOutput::new();
        out.publish_frame(frame(7));
        out.reject(tonic::Code::InvalidArgument, "a");
        out.reject(tonic::Code::InvalidArgument, "b");
        for expect in ["a", "b"] {
            match out.try_next().unwrap().msg {
                Some(server_msg::Msg::Rejected(r)) => {
                    assert_eq!(r.message, expect);
                    assert_eq!(r.code, 3);
                }
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(seq_of(out.try_next().unwrap()), 7);
        for i in 0..MAX_QUEUED_REJECTIONS + 10 {
            out.reject(tonic::Code::InvalidArgument, format!("{i}"));
        }
        let mut n = 0;
        while out.try_next().is_some() {
            n += 1;
        }
        assert_eq!(n, MAX_QUEUED_REJECTIONS);
    }

    #[test]
    fn progress_is_latest_wins_per_stage_in_stage_order() {
        let out = SessionOutput::new();
        let p = |stage: &str, done| Progress { stage: stage.into(), done, total: 10, message: String::new() };
        out.publish_frame(frame(1));
        out.progress(p("workers", 0));
        out.progress(p("edge trees", 3));
        out.progress(p("workers", 1));
        out.progress(p("edge trees", 4));
        for (stage, done) in [("workers", 1), ("edge trees", 4)] {
            match out.try_next().unwrap().msg {
                Some(server_msg::Msg::Progress(q)) => assert_eq!((q.stage.as_str(), q.done), (stage, done)),
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(seq_of(out.try_next().unwrap()), 1);
        assert!(out.try_next().is_none());
    }

    #[test]
    fn pick_answers_queue_ahead_of_frames() {
        let out = SessionOutput::new();
        out.publish_frame(frame(3));
        out.picked(Picked { id: 11, ..Default::default() });
        match out.try_next().unwrap().msg {
            Some(server_msg::Msg::Picked(p)) => assert_eq!(p.id, 11),
            other => panic!("{other:?}"),
        }
        assert_eq!(seq_of(out.try_next().unwrap()), 3);
    }

    #[tokio::test]
    async fn next_wakes_on_publish_and_ends_after_end() {
        let out = std::sync::Arc::new(SessionOutput::new());
        let o2 = out.clone();
        let t = std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(20));
            o2.publish_frame(frame(9));
            o2.end();
        });
        assert_eq!(seq_of(out.next().await.unwrap()), 9);
        assert!(out.next().await.is_none());
        out.done().await;
        t.join().unwrap();
    }
}
